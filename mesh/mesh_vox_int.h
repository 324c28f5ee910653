/* mesh_vox_int — what the files of the mesh voxelizer share; not an
 * interface of the module (mesh_vox.h is).
 *
 * Exact arithmetic.  A pass samples the grid at K samples per voxel and
 * axis (K = 1: voxel centres; K = supersample: the density's samples).
 * Every vertex is mapped once, by one formula, to a lattice of 2^16 units
 * per sample spacing, relative to the grid's low corner, and rounded to the
 * nearest unit (mesh_vox_snap): the mesh that is voxelized is that snapped mesh,
 * at most 2^-17 sample spacing from the given one, and since a vertex
 * shared by two triangles is snapped once, a closed mesh stays closed.
 * From there on every decision (a sample inside a projected triangle, a
 * sample above or below a triangle's plane, a voxel box touching a
 * triangle) is an exact sign of integer arithmetic in 64 and 128 bits:
 * coordinates are clamped to +-2^40 units (2^24 sample spacings from the
 * grid, far past any grid), so edge functions stay below 2^84 and their
 * products with a coordinate below 2^126.
 *
 * Sample i along an axis is centred at lattice coordinate i * L + L/2;
 * voxel X holds the samples X*K .. X*K + K - 1.
 */
#ifndef VOXD_MESH_VOX_INT_H
#define VOXD_MESH_VOX_INT_H

#include <float.h>
#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>
#include <string.h>

#include "mesh_vox.h"
#include "bits.h"

#if defined(__FAST_MATH__) || defined(__ASSOCIATIVE_MATH__)
#error "the mesh voxelizer's rounding (mesh_vox_snap) needs IEEE arithmetic: no -ffast-math"
#endif

__extension__ typedef __int128 mesh_vox_i128;

#define MESH_VOX_QBITS 16
#define MESH_VOX_L ((int64_t)1 << MESH_VOX_QBITS) /* lattice units per sample spacing */
#define MESH_VOX_H (MESH_VOX_L / 2)
#define MESH_VOX_LIM 1099511627776.0 /* 2^40: the coordinates' clamp */

/* A tile's heartbeat (mesh_tile_env.tick).  The long loops count their
 * work in units of about 10 ns (a triangle's solid angle at one point; a
 * triangle rasterized is 8) and tick every MESH_VOX_BEAT units, a fraction of a
 * millisecond; once a tick said stop, stop stays set, the loops end early
 * and the tile returns -ECANCELED. */
#define MESH_VOX_BEAT 16384u
typedef struct {
    const mesh_tile_env *env; /* NULL: no heartbeat */
    uint32_t work;            /* units since the last tick */
    bool stop;
    int err;                  /* why a loop set stop, when not a tick: the
                                 tile's error (0: -ECANCELED) */
} mesh_vox_pulse;

/* units of work done (p may be NULL): ticks when due; true once the tile
 * must stop. */
static inline bool mesh_vox_beat(mesh_vox_pulse *p, uint32_t units)
{
    if (!p) return false;
    p->work += units;
    if (p->work >= MESH_VOX_BEAT) {
        p->work = 0;
        if (p->env && p->env->tick && p->env->tick(p->env->arg)) p->stop = true;
    }
    return p->stop;
}

/* The lattice of one pass: lattice = (v - lo) * scale. */
typedef struct {
    const mesh *m;
    const mesh_lattice *lat; /* K = 1: the vertices snapped already, or NULL */
    double lo[3];
    double scale;   /* lattice units per world unit: K * L / vs */
    uint32_t K;     /* samples per voxel and axis */
    mesh_vox_pulse *pulse; /* the tile's heartbeat, or NULL */
    const mesh_wtree *wt; /* the winding numbers' tree, or NULL: the exact sum */
    const mesh_wtree *caps; /* whose caps give a capped block's parities
                               (wt, or the tile's own), or NULL */
} mesh_vox_frame;

void mesh_vox_frame_init(mesh_vox_frame *f, const mesh *m, const grid_spec *g, uint32_t K);

/* Nearest lattice point of t (in lattice units), clamped to +-2^40 (NaN to
 * -2^40).  The rounding is the FPU's round-to-nearest: adding and taking
 * away 1.5 * 2^52 leaves the nearest integer of any |t| < 2^51.  That
 * needs the sum rounded to a double and kept apart from the difference:
 * no reassociation (refused above) and, where the FPU computes in more
 * than double precision, a store. */
static inline int64_t mesh_vox_snap(double t)
{
    t = t > -MESH_VOX_LIM ? t : -MESH_VOX_LIM; /* NaN too: max and min, no branch */
    t = t < MESH_VOX_LIM ? t : MESH_VOX_LIM;
#if FLT_EVAL_METHOD == 0
    double r = t + 6755399441055744.0;
#else
    volatile double r = t + 6755399441055744.0;
#endif
    return (int64_t)(r - 6755399441055744.0);
}

/* Coordinate a of vertex v, snapped. */
static inline int64_t mesh_vox_vertex(const mesh_vox_frame *f, uint32_t v, int a)
{
    return mesh_vox_snap(((double)f->m->vertices[v][a] - f->lo[a]) * f->scale);
}

/* The snapped vertices of triangle t: P[vertex][axis]. */
static inline void mesh_vox_triangle(const mesh_vox_frame *f, uint32_t t, int64_t P[3][3])
{
    const uint32_t *tri = f->m->triangles[t];
    if (f->lat) {
        for (int i = 0; i < 3; i++) memcpy(P[i], f->lat[tri[i]], sizeof P[i]);
        return;
    }
    for (int i = 0; i < 3; i++)
        for (int a = 0; a < 3; a++) P[i][a] = mesh_vox_vertex(f, tri[i], a);
}

/* The vertices of triangle t are about to be read (snapped already, or
 * not): fetch them now (their indices make the reads random, and most of
 * a small triangle's cost is waiting for them). */
#define MESH_VOX_AHEAD 12 /* triangles */
static inline void mesh_vox_prefetch(const mesh_vox_frame *f, uint32_t t)
{
    const uint32_t *tri = f->m->triangles[t];
    for (int i = 0; i < 3; i++) {
        if (f->lat) { /* 24 bytes: maybe two cache lines */
            __builtin_prefetch(f->lat[tri[i]]);
            __builtin_prefetch(&f->lat[tri[i]][2]);
        } else {
            __builtin_prefetch(f->m->vertices[tri[i]]);
        }
    }
}

/* floor(a / L) and ceil(a / L) by shifts: >> of a negative value is
 * arithmetic (floor) with the compilers this builds with, checked here. */
_Static_assert((-3 >> 1) == -2 && (-((int64_t)1 << 40) >> 16) == -((int64_t)1 << 24),
               "right shifts of negative values are arithmetic");
static inline int64_t mesh_vox_floor_l(int64_t a) { return a >> MESH_VOX_QBITS; }
static inline int64_t mesh_vox_ceil_l(int64_t a) { return -(-a >> MESH_VOX_QBITS); }

/* A block of samples: s0 + [0, n) per axis, one bit each, x fastest, rows
 * of nw 64-bit words: bit x of word ((z * n[1] + y) * nw + x / 64), all
 * relative to s0.  Bits past n[0] in a row stay 0. */
typedef struct {
    int64_t s0[3];
    int32_t n[3];
    uint32_t nw;
} mesh_vox_block;

static inline size_t mesh_vox_block_words(const mesh_vox_block *b)
{
    return (size_t)b->n[2] * (size_t)b->n[1] * b->nw;
}

/* The bits of x in [lo[0], hi[0]) in their word (a cell's row: at most 64
 * samples, within one word). */
static inline uint64_t mesh_vox_xmask(const uint32_t lo[3], const uint32_t hi[3])
{
    uint32_t s = lo[0] & 63, n = hi[0] - lo[0];
    return (n == 64 ? ~0ull : ((1ull << n) - 1)) << s;
}

/* The word of a bit array of block b's layout that holds sample (x, y, z). */
static inline size_t mesh_vox_word(const mesh_vox_block *b, uint32_t x, uint32_t y, uint32_t z)
{
    return ((size_t)z * (size_t)b->n[1] + y) * b->nw + x / 64;
}

/* The bits set in cell [lo, hi) of bits, a bit array of block b's layout. */
static inline uint64_t mesh_vox_cell_count(const mesh_vox_block *b, const uint64_t *bits,
                                     const uint32_t lo[3], const uint32_t hi[3])
{
    uint64_t mask = mesh_vox_xmask(lo, hi), n = 0;
    for (uint32_t z = lo[2]; z < hi[2]; z++)
        for (uint32_t y = lo[1]; y < hi[1]; y++)
            n += bits_popcount64(bits[mesh_vox_word(b, lo[0], y, z)] & mask);
    return n;
}

/* The bits set in cell [lo, hi) of bits, as mesh_vox_cell_count, and the
 * cell shrunk to their bounding box in [blo, bhi) (unset when none). */
static inline uint64_t mesh_vox_cell_box(const mesh_vox_block *b, const uint64_t *bits,
                                         const uint32_t lo[3], const uint32_t hi[3],
                                         uint32_t blo[3], uint32_t bhi[3])
{
    uint64_t mask = mesh_vox_xmask(lo, hi), n = 0, any = 0;
    uint32_t ylo = hi[1], yhi = 0, zlo = hi[2], zhi = 0;
    for (uint32_t z = lo[2]; z < hi[2]; z++)
        for (uint32_t y = lo[1]; y < hi[1]; y++) {
            uint64_t w = bits[mesh_vox_word(b, lo[0], y, z)] & mask;
            if (!w) continue;
            n += bits_popcount64(w);
            any |= w;
            ylo = y < ylo ? y : ylo, yhi = y + 1 > yhi ? y + 1 : yhi;
            zlo = z < zlo ? z : zlo, zhi = z + 1;
        }
    if (!n) return 0;
    uint32_t base = lo[0] / 64 * 64;
    blo[0] = base + (uint32_t)__builtin_ctzll(any), bhi[0] = base + 64 - (uint32_t)__builtin_clzll(any);
    blo[1] = ylo, bhi[1] = yhi, blo[2] = zlo, bhi[2] = zhi;
    return n;
}

/* The samples of a cell to decide at once (mesh_vox_cell_decide). */
typedef struct {
    const mesh_vox_block *b;
    const uint64_t *sel;   /* the samples to decide */
    uint64_t *bits;        /* their answers */
    uint64_t *done;        /* NULL, or the samples to do: the decided ones cleared */
    const uint16_t *count; /* NULL: every sample inside when k != 0; else
                              inside where its count is not k */
} mesh_vox_decide;

/* Every sample of cell [lo, hi) set in d->sel into d->bits (mesh_wind.c's
 * whole cells and mesh_wcap.c's cells by their counts). */
static inline void mesh_vox_cell_decide(const mesh_vox_decide *d, const uint32_t lo[3],
                                        const uint32_t hi[3], uint16_t k)
{
    uint64_t mask = mesh_vox_xmask(lo, hi);
    for (uint32_t z = lo[2]; z < hi[2]; z++)
        for (uint32_t y = lo[1]; y < hi[1]; y++) {
            size_t i = mesh_vox_word(d->b, lo[0], y, z);
            uint64_t s = d->sel[i] & mask, in = k ? s : 0;
            if (d->count) {
                const uint16_t *n = d->count + i * 64;
                in = 0;
                for (uint64_t r = s; r; r &= r - 1) {
                    unsigned x = (unsigned)__builtin_ctzll(r);
                    in |= (uint64_t)(n[x] != k) << x;
                }
            }
            d->bits[i] = (d->bits[i] & ~s) | in;
            if (d->done) d->done[i] &= ~s;
        }
}

/* Block b cut in cells top samples a side, x fastest: [lo, hi) becomes
 * the cell after it (the first where hi is all 0); false past the last. */
static inline bool mesh_vox_top_next(const mesh_vox_block *b, uint32_t top, uint32_t lo[3], uint32_t hi[3])
{
    int a = 0;
    if (!hi[0] && !hi[1] && !hi[2]) {
        lo[0] = lo[1] = lo[2] = 0;
    } else {
        for (; a < 3 && hi[a] >= (uint32_t)b->n[a]; a++) lo[a] = 0;
        if (a == 3) return false;
        lo[a] += top;
    }
    for (a = 0; a < 3; a++) hi[a] = lo[a] + top < (uint32_t)b->n[a] ? lo[a] + top : (uint32_t)b->n[a];
    return hi[0] > lo[0] && hi[1] > lo[1] && hi[2] > lo[2];
}

/* Half q (bit a: the upper half along axis a) of cell [lo, hi) into
 * [clo, chi); false when it is empty (an axis one sample long). */
static inline bool mesh_vox_half(const uint32_t lo[3], const uint32_t hi[3], int q, uint32_t clo[3],
                                 uint32_t chi[3])
{
    bool some = true;
    for (int a = 0; a < 3; a++) {
        uint32_t ext = hi[a] - lo[a], mid = lo[a] + (ext + 1) / 2, up = q >> a & 1;
        clo[a] = up ? mid : lo[a];
        chi[a] = up ? hi[a] : mid;
        some &= clo[a] < chi[a];
    }
    return some;
}

/* Where the crossings of one ray direction go (mesh_vox_raster).
 *  z: flip the bit of the first sample past the crossing in `bits`; a
 *     crossing below the block flips its first slice when first_z (the
 *     block starts the column), else it was counted before (the carry).
 *  x: the same along x; a crossing left of the block toggles the row's bit
 *     in `carry` (bit z * n[1] + y).
 *  y: the same along y; a crossing in front of the block toggles bit x of
 *     `carry` word z * nw + x / 64.
 *  Crossings past the block's end are dropped.
 *  count (z only, or NULL): one 16-bit counter a sample (index bit index *
 *     64 + bit), the crossing's sign added (+1 for a triangle facing down,
 *     -1 up), so that the prefix sum along z is the signed count of the
 *     crossings below, modulo 2^16 (a ray would need 32768 more crossings
 *     one way than the other to wrap); bits may then be NULL. */
typedef struct {
    const mesh_vox_block *b;
    uint64_t *bits, *carry;
    bool first_z;
    uint16_t *count;
} mesh_vox_target;

/* Rasterize snapped triangle P along ray axis (0 x, 2 y... see mesh_vox_raster). */
void mesh_vox_raster(const int64_t P[3][3], int axis, const mesh_vox_target *t);

/* Parity from flips: z by XOR from slice to slice, starting from carry
 * (one word per (y, x-word): the parities below the block) unless first,
 * and leaving the last slice in carry (NULL: none kept); x by a prefix XOR
 * along each row from its carry bit; y by XOR from row to row from the
 * carry words. */
void mesh_vox_prefix_z(const mesh_vox_block *b, uint64_t *bits, uint64_t *carry, bool first);
void mesh_vox_prefix_x(const mesh_vox_block *b, uint64_t *bits, const uint64_t *carry);
void mesh_vox_prefix_y(const mesh_vox_block *b, uint64_t *bits, const uint64_t *carry);

/* The parity along z (and, with repair, along x and y and the decision) of
 * block b's samples, from the triangles ids[0, n).  bits: the result;
 * bx, by, cx, cy: the repair's buffers (NULL without repair); zcarry:
 * n[1] * nw words, the column parities below the block in and its last
 * slice out (see mesh_vox_prefix_z; NULL for a block through the whole column).
 * When dis is not NULL, the samples whose three parities differ are set
 * there (repair only).  Returns the number of those samples. */
typedef struct {
    const mesh_vox_frame *f;
    const uint32_t *ids;
    size_t n;
    mesh_repair repair;
    bool first;        /* the block starts the column */
    double zlo, zhi;   /* world z range of the block (for culling), or NaN */
    bool capped;       /* the plan's (a K = 1 block through the whole column,
                          with dis and f->caps): the parities along x and y
                          from the caps' */
} mesh_vox_solid_in;
typedef struct {
    uint64_t *bits, *bx, *by, *cx, *cy, *zcarry, *dis;
    uint16_t *count; /* a counter a sample for the capped winding numbers
                        (mesh_wcap.c; K = 1 blocks through the whole
                        column), or NULL */
} mesh_vox_solid_buf;
uint64_t mesh_vox_solid(const mesh_vox_solid_in *in, const mesh_vox_block *b, const mesh_vox_solid_buf *buf);

/* The generalized winding numbers w[k] of the mesh at points q[k], k < n
 * (in the frame's sample units: sample i is centred at i + 0.5). */
void mesh_vox_winding_many(const mesh_vox_frame *f, const double (*q)[3], unsigned n, double *w);

/* The solid angle of triangle (a, b, c) seen from the origin, over 2
 * (Van Oosterom and Strackee); the distance from p to triangle v. */
double mesh_vox_half_solid_angle(const double a[3], const double b[3], const double c[3]);
/* The same, and its parts: the triple product a.(b x c), the denominator
 * (|a||b||c| + (a.b)|c| + (b.c)|a| + (c.a)|b|) and |a||b||c|. */
double mesh_vox_half_solid_angle_parts(const double a[3], const double b[3], const double c[3],
                                       double *det, double *den, double *l);
double mesh_vox_tri_dist(const double v[3][3], const double p[3]);

/* The fast winding number (mesh_wind.c), in voxel units ((v - lo) / vs).
 * mesh_vox_wtree_make: the tree of m's triangles, or (m NULL) of the n triangles
 * tri (voxel units), ticking pulse (may be NULL) as it goes.  mesh_vox_wind_point: w at p, far nodes by their expansion
 * where |c - p| > beta r (work: node visits added).  mesh_vox_wind_cell: w at b
 * and in *err a bound of |w(p) - *w| for every p within rho of b, a node
 * by its expansion where |c - b| > 2 (r + rho) and its bound is at most
 * tol (INFINITY: the first rule alone); false (and no bound) when a
 * triangle comes within rho of b or the bound passes emax.  With a near
 * list, the triangles within 3 (rho + 1) of the ball are left out of *w
 * and listed there instead (false when more than MESH_VOX_NEAR_MAX).
 * mesh_vox_wind_near: the listed triangles' w at p, and *is_close set when p
 * lies within close of one's plane and ball (where the sign of its angle
 * may differ from the raster's side of it). */
typedef struct mesh_vox_wtree mesh_vox_wtree;
/* A cell query's ball (centre b, radius rho of its samples, 0: a point)
 * and limits: a node taken whole where its bound is at most tol, false
 * where the summed bound passes emax. */
typedef struct {
    double b[3], rho, tol, emax;
} mesh_vox_wball;
/* Triangles of a tree: tri[k] (leaf order) of leaf leaf[k], k < n. */
typedef struct {
    const uint32_t *tri, *leaf;
    uint32_t n;
} mesh_vox_tris;
int mesh_vox_wtree_make(const mesh *m, const grid_spec *g, const double (*tri)[3][3], uint32_t n,
                  mesh_vox_pulse *pulse, mesh_vox_wtree **out);
void mesh_vox_wtree_free(mesh_vox_wtree *t);
double mesh_vox_wind_point(const mesh_vox_wtree *t, const double p[3], double beta, uint32_t *work);
#define MESH_VOX_NEAR_MAX 32
typedef struct {
    uint32_t n, tri[MESH_VOX_NEAR_MAX], leaf[MESH_VOX_NEAR_MAX];
} mesh_vox_near;
bool mesh_vox_wind_cell(const mesh_vox_wtree *t, const mesh_vox_wball *q, mesh_vox_near *near, double *w,
                        double *err, uint32_t *work);
double mesh_vox_wind_near(const mesh_vox_wtree *t, const mesh_vox_near *near, const double p[3], double close,
                    bool *is_close);
/* mesh_vox_wind_tris: mesh_vox_wind_near's sum over the triangles s. */
double mesh_vox_wind_tris(const mesh_vox_wtree *t, const mesh_vox_tris *s, const double p[3], double close,
                          bool *is_close);
/* The far field handed down from a cell to its halves (a dual-tree
 * descent): nodes node[0, n_node) and triangles tri[k] of leaves leaf[k],
 * k < n_tri, still to take, and 4 pi times the value w4 of those taken
 * and the bound e4 of its error over the cell's ball.  mesh_vox_wind_down:
 * in's part at the cell q (its b, rho) into out (room for cap of each): a node
 * by its expansion (beta 2) or its magnitude (area / f^2) where that bound
 * is at most tol, a triangle by its exact angle and gradient bound where
 * it keeps NEAR_REACH (rho + 1) voxels off the ball; else a node no larger
 * than the cell and a triangle are handed down (rho = 0: none is, but the
 * triangles within 3 voxels of b, for mesh_vox_wind_tris).  false when a
 * list would overflow or e4 passes 4 pi emax.  A root list: node 0. */
typedef struct {
    uint32_t n_node, n_tri, cap;
    uint32_t *node, *tri, *leaf;
    double w4, e4;
} mesh_vox_wlist;
bool mesh_vox_wind_down(const mesh_vox_wtree *t, const mesh_vox_wlist *in, const mesh_vox_wball *q,
                        mesh_vox_wlist *out, uint32_t *work);
/* A bound of |w(p)| for every p within rho of b (a node of area a whose
 * ball keeps f away subtends at most a / f^2, taken where that is at most
 * tol); false when a leaf's ball meets the cell's or the bound passes
 * emax.  Cheap where the triangles are small (the caps of small holes). */
bool mesh_vox_wind_mag(const mesh_vox_wtree *t, const mesh_vox_wball *q, double *bound, uint32_t *work);
/* The samples of block b set in dis decided by the winding number of tree
 * t (inside: |w| >= 1/2) into bits, cells of samples at once where the
 * bound decides them, else sample by sample: the tree, then, near 1/2, the
 * exact sum (mesh_vox_winding_many). */
void mesh_vox_wind_block(const mesh_vox_frame *f, const mesh_vox_wtree *t, const mesh_vox_block *b, const uint64_t *dis,
                   uint64_t *bits);

/* The capped winding numbers (mesh_wcap.c): the samples of block b set in
 * dis decided into bits by f->wt.  count: the block's counters filled by
 * the z raster of the mesh (mesh_vox_target), or NULL: mesh_vox_wind_block alone.
 * dis and spare: overwritten (spare: a block of words). */
void mesh_vox_wcap_block(const mesh_vox_frame *f, const mesh_vox_block *b, uint64_t *dis, uint64_t *bits,
                   uint16_t *count, uint64_t *spare);
/* The caps' parities (mesh_wcap.c), for a K = 1 block through the whole
 * column: the mesh S with its caps C is closed, so on every sample its
 * parities along x, y and z are those of S's along z and C's,
 *     p_r(S) = p_z(S) ^ p_z(C) ^ p_r(C),
 * and they disagree exactly where C's do.  mesh_vox_wcap_ready builds
 * f->caps's caps (0, or the build's error); mesh_vox_wcap_parities
 * rasterizes them along z into cz (zeroed first), along x into cx
 * (carries kx) and along y into cy (carries ky), which the caller zeroed
 * as for S's own rasters, and leaves each a parity (the prefix passes done). */
int mesh_vox_wcap_ready(const mesh_vox_frame *f);
void mesh_vox_wcap_parities(const mesh_vox_frame *f, const mesh_vox_block *b, uint64_t *cz,
                            uint64_t *cx, uint64_t *kx, uint64_t *cy, uint64_t *ky);
/* The caps' expansion about b (mesh_wcap.c's direct path): for every p
 * within rho of b, |w(p) - v - g.(p - b)| <= e, w the winding number of
 * the n triangles tri (their edges 0 -> 1 their boundary, as a cap's fan:
 * the other edges cancel), ball about each (centre, radius) or NULL;
 * false when a triangle comes within rho + 0.001 of b. */
typedef struct {
    double v, g[3], e;
} mesh_vox_cexp;
bool mesh_vox_wcap_expand(const double (*tri)[3][3], const double (*ball)[4], uint32_t n,
                    const double b[3], double rho, mesh_vox_cexp *x);
/* For the tests: nonzero, the caps' tree even where they are few enough
 * for the direct path (every cap triangle at every cell). */
extern int mesh_wcap_tree_only;
/* For the tests: the samples mesh_wcap.c's caps' exact sum left to the
 * mesh's exact sum (on a cap triangle, or |N - w_C| within 1e-6 of 1/2),
 * counted since the process began (relaxed: read after the job returns). */
extern _Atomic uint64_t mesh_wcap_to_exact;

/* Surface bits (K = 1 blocks): every voxel of block b whose closed box
 * triangle P touches (six = false), or its 6-separating subset. */
void mesh_vox_surface(const int64_t P[3][3], bool six, const mesh_vox_block *b, uint64_t *bits);

/* ---- a tile (mesh_vox.c, mesh_density.c) ---- */

/* What the options need, from the grid and the options alone. */
typedef struct {
    bool solid1;     /* the parity solid at voxel centres */
    bool surf;       /* the surface bits */
    bool dens;       /* the supersampled coverage (density or normals) */
    bool rep;        /* parities along x and y too */
    bool count;      /* the counters of the capped winding numbers */
    bool capped;     /* the parities along x and y from the caps' (no rows
                        of triangles in the bins: mesh_vox_wcap_parities) */
    bool every_tile; /* mesh_vox_every_tile */
    uint32_t apron;  /* 1: the coverage of the voxels around the tile too */
    uint32_t K;      /* samples per voxel and axis of the coverage */
    uint32_t nz;     /* voxels along z */
    uint32_t fnw;    /* words per row of a fine block */
    uint32_t zs;     /* voxel slices per fine block */
    uint32_t ring;   /* voxel slices of counts kept */
    bool dist;       /* the signed distance (channel 4) */
    uint32_t band;   /* its band, voxels */
} mesh_vox_plan;

/* The scratch's buffers (NULL where the plan needs none). */
typedef struct {
    uint64_t *a, *bx, *by, *cx, *cy, *surf, *dis; /* voxel bits of the tile */
    uint16_t *count;                              /* mesh_vox_solid_buf's */
    uint8_t *brick;                               /* one storage brick */
    uint64_t *fa, *fzc, *fbx, *fby, *fcx, *fcy, *fdis; /* fine blocks */
    uint16_t *ring;                               /* coverage counts */
    double *d2;                                   /* a slab's squared distances (mesh_dist.c) */
} mesh_vox_bufs;

void mesh_vox_plan_make(const grid_spec *g, const mesh_vox_opts *o, mesh_vox_plan *p);
size_t mesh_vox_layout(const mesh_vox_plan *p, uint32_t bits, void *base, mesh_vox_bufs *b);

typedef struct {
    const mesh *m;
    const mesh_lattice *lat;    /* K = 1 vertices, or NULL */
    const grid_spec *g;
    const mesh_vox_opts *o;
    const uint32_t *ids;
    size_t n;
    vod_volume *vol;
    uint32_t S;                 /* the volume's storage brick side */
    uint32_t x0, y0;            /* the tile's first voxel */
    uint32_t nx, ny, nz;        /* its voxels (nx, ny <= MESH_TILE) */
    const uint64_t *occ;        /* the mode's voxel bits: word z * ny + y */
    uint64_t *dis;              /* voxels whose parities differ, or NULL */
    mesh_tile_stats *st;
    mesh_vox_pulse pulse;             /* the heartbeat of every pass of the tile */
    const mesh_wtree *caps;     /* the caps of a capped plan (mesh_vox_frame's) */
} mesh_vox_tile;

/* The density channel's bricks, or the surface channel's (occupancy from
 * t->occ, normals from the coverage). */
int mesh_vox_density_run(mesh_vox_tile *t, const mesh_vox_plan *p, const mesh_vox_bufs *b);
/* The distance channel's bricks (mesh_dist.c): the signed distance of
 * every voxel within the band, the sign from t->occ (the solid). */
int mesh_vox_dist_run(mesh_vox_tile *t, const mesh_vox_plan *p, const mesh_vox_bufs *b);

#endif
