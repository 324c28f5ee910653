/* mesh_wind — the fast winding number of Barill, Dickson, Schmidt, Levin
 * and Jacobson ("Fast Winding Numbers for Soups and Clouds", SIGGRAPH
 * 2018): a bounding-volume tree over the triangles whose nodes carry the
 * dipole expansion of their triangles' solid angles (orders 1 and 2); far
 * nodes are taken by their expansion, near ones triangle by triangle
 * (Van Oosterom and Strackee's exact solid angle).
 *
 * Units: voxels of the job's grid from its low corner ((v - lo) / vs), so
 * the tree serves every pass of a tile (K = 1 and the density's K).
 *
 * The expansion of node N (triangles t of area a_t, unit normal n_t,
 * centroid x_t; c the area-weighted centroid, every vertex within r of c)
 * seen from p, d = c - p, R = |d|:
 *     4 pi w_N ~ m.d / R^3 + tr(P) / R^3 - 3 d.P d / R^5,
 *     m = sum a_t n_t,  P = sum a_t n_t (x_t - c)^T,
 * the Taylor series of the dipole kernel n.(x - p) / |x - p|^3 around
 * x = c to its linear term.  The kernel is D(1/|y|)[n] and
 * |D^k (1/|y|)[u1..uk]| <= k! / |y|^(k+1) for unit vectors (Legendre's
 * bound, and Banach's theorem on symmetric forms), so the remainder of a
 * node is at most
 *     area * 3 r^2 / (R - r)^4 / (4 pi)                       (1)
 * and the value at any p within rho of a point b differs from the one at
 * b by at most
 *     area * 2 rho / (R - r - rho)^3 / (4 pi)                  (2)
 * (area: the sum of |a_t|; R measured from b).
 */
#include "mesh_vox_int.h"

#include <errno.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#define LEAF 8 /* triangles at most in a leaf */

/* A node as the descents read it, 32 bytes: two siblings (first, first +
 * 1: an odd index and the next) share one cache line (mesh_vox_wtree_make
 * aligns the odd ones); its moments, read only where it is expanded, apart. */
typedef struct {
    float c[3], r;   /* centre, radius */
    float area;
    uint32_t first;  /* leaf: its first triangle (leaf order); else its first child */
    uint32_t count;  /* leaf: its triangles; 0: an inner node (children first, first + 1) */
    uint32_t pad;
} wnode;

typedef struct {
    float m[3];      /* sum a n */
    float P[9];      /* P[3 i + j] = sum a n_i (x - c)_j */
} wmom;

_Static_assert(sizeof(wnode) == 32, "two nodes a cache line");

struct mesh_vox_wtree {
    wnode *nodes;    /* node i at nodes[i], inside block (nodes + 1 is 64-aligned) */
    wmom *mom;       /* node i's moments */
    void *block;
    uint32_t n_nodes;
    float (*tri)[9]; /* the triangles' vertices in leaf order, voxel units
                        relative to their leaf's centre */
    double (*tdip)[8]; /* for a tree of given triangles (the caps), each one's
                          centroid (from its leaf's centre), radius about it
                          (rounding inside), area vector and area: down_tri's */
};

/* ---- building ---- */

typedef struct {
    const mesh *m;
    const grid_spec *g;
    const double (*vt)[3][3]; /* without m: the triangles, voxel units */
    double (*cen)[3]; /* triangle centroids */
    uint32_t *ids;    /* triangle ids, permuted into leaf order */
    mesh_vox_wtree *t;
    mesh_vox_pulse *pulse;  /* ticked as the nodes are made, or NULL */
} builder;

static void tri_voxels(const builder *b, uint32_t id, double p[3][3])
{
    if (!b->m) {
        memcpy(p, b->vt[id], sizeof b->vt[id]);
        return;
    }
    for (int i = 0; i < 3; i++) {
        const float *v = b->m->vertices[b->m->triangles[id][i]];
        for (int a = 0; a < 3; a++) p[i][a] = ((double)v[a] - b->g->lo[a]) / b->g->vs;
    }
}

static bool before(const builder *b, uint32_t x, uint32_t y, int axis)
{
    double u = b->cen[x][axis], v = b->cen[y][axis];
    return u < v || (u == v && x < y); /* ties by id: one order whatever */
}

/* ids[lo, hi) arranged so that ids[k] is the k-th along axis and no id
 * before it comes after it (a quickselect, pivot the median of three). */
static void select_kth(const builder *b, uint32_t lo, uint32_t hi, uint32_t k, int axis)
{
    uint32_t *a = b->ids;
    while (hi - lo > 2) {
        uint32_t mid = lo + (hi - lo) / 2, x = a[lo], y = a[mid], z = a[hi - 1];
        uint32_t piv = before(b, x, y, axis) ? (before(b, y, z, axis) ? y : before(b, x, z, axis) ? z : x)
                                             : (before(b, x, z, axis) ? x : before(b, y, z, axis) ? z : y);
        uint32_t i = lo, j = hi - 1;
        for (;;) { /* Hoare's partition around the value piv */
            while (before(b, a[i], piv, axis)) i++;
            while (before(b, piv, a[j], axis)) j--;
            if (i >= j) break;
            uint32_t s = a[i];
            a[i] = a[j], a[j] = s;
            i++, j--;
        }
        if (k <= j) hi = j + 1;
        else lo = j + 1;
    }
    if (hi - lo == 2 && before(b, a[lo + 1], a[lo], axis)) {
        uint32_t s = a[lo];
        a[lo] = a[lo + 1], a[lo + 1] = s;
    }
}

/* Triangle v's (9 floats, as stored) centroid, radius about it, area
 * vector and area, in double: down_tri's dipole and bounds. */
static void tri_dipole(const float *v, double x[8])
{
    double e1[3], e2[3], r2 = 0;
    for (int i = 0; i < 3; i++) {
        x[i] = ((double)v[i] + v[3 + i] + v[6 + i]) / 3;
        e1[i] = (double)v[3 + i] - v[i], e2[i] = (double)v[6 + i] - v[i];
    }
    for (int j = 0; j < 3; j++) {
        double s = 0;
        for (int i = 0; i < 3; i++) s += (v[3 * j + i] - x[i]) * (v[3 * j + i] - x[i]);
        r2 = s > r2 ? s : r2;
    }
    x[3] = sqrt(r2) * (1 + 1e-6);
    x[4] = 0.5 * (e1[1] * e2[2] - e1[2] * e2[1]);
    x[5] = 0.5 * (e1[2] * e2[0] - e1[0] * e2[2]);
    x[6] = 0.5 * (e1[0] * e2[1] - e1[1] * e2[0]);
    x[7] = sqrt(x[4] * x[4] + x[5] * x[5] + x[6] * x[6]);
}

/* Leaf n over ids[first, first + count): its moments from the triangles
 * in double, then the triangles into tri[], relative to its centre (small
 * numbers: a float keeps them to 6e-8 of the leaf's radius). */
static void make_leaf(const builder *b, wnode *n, wmom *mo)
{
    double area = 0, cx[3] = {0, 0, 0}, M[3] = {0, 0, 0}, P[9] = {0};
    double v[LEAF][3][3], an[LEAF][3], xc[LEAF][3], ar[LEAF];
    for (uint32_t k = 0; k < n->count; k++) {
        tri_voxels(b, b->ids[n->first + k], v[k]);
        double e1[3], e2[3];
        for (int a = 0; a < 3; a++) {
            e1[a] = v[k][1][a] - v[k][0][a];
            e2[a] = v[k][2][a] - v[k][0][a];
            xc[k][a] = (v[k][0][a] + v[k][1][a] + v[k][2][a]) / 3;
        }
        an[k][0] = 0.5 * (e1[1] * e2[2] - e1[2] * e2[1]);
        an[k][1] = 0.5 * (e1[2] * e2[0] - e1[0] * e2[2]);
        an[k][2] = 0.5 * (e1[0] * e2[1] - e1[1] * e2[0]);
        ar[k] = sqrt(an[k][0] * an[k][0] + an[k][1] * an[k][1] + an[k][2] * an[k][2]);
        area += ar[k];
        for (int a = 0; a < 3; a++) cx[a] += ar[k] * xc[k][a], M[a] += an[k][a];
    }
    for (int a = 0; a < 3; a++) {
        n->c[a] = (float)(area > 0 ? cx[a] / area : xc[0][a]);
        cx[a] = n->c[a]; /* the centre as stored */
        mo->m[a] = (float)M[a];
    }
    double r2 = 0;
    for (uint32_t k = 0; k < n->count; k++) {
        float *out = b->t->tri[n->first + k];
        for (int i = 0; i < 3; i++) {
            double s = 0;
            for (int a = 0; a < 3; a++) {
                out[3 * i + a] = (float)(v[k][i][a] - cx[a]);
                s += (v[k][i][a] - cx[a]) * (v[k][i][a] - cx[a]);
            }
            r2 = s > r2 ? s : r2;
        }
        for (int i = 0; i < 3; i++)
            for (int j = 0; j < 3; j++) P[3 * i + j] += an[k][i] * (xc[k][j] - cx[j]);
    }
    for (int i = 0; i < 9; i++) mo->P[i] = (float)P[i];
    for (uint32_t k = 0; b->t->tdip && k < n->count; k++) tri_dipole(b->t->tri[n->first + k], b->t->tdip[n->first + k]);
    n->area = (float)area;
    n->r = (float)(sqrt(r2) * (1 + 1e-6)); /* the floats' rounding inside */
}

/* Inner node n from its children: P moved to the new centre
 * (P_child + m_child (c_child - c)^T), the radius bounded by the
 * children's balls. */
static void inner_moments(wnode *n, wmom *mo, const wnode *k, const wmom *km)
{
    double area = (double)k[0].area + k[1].area, c[3];
    for (int a = 0; a < 3; a++) {
        c[a] = area > 0 ? ((double)k[0].area * k[0].c[a] + (double)k[1].area * k[1].c[a]) / area
                        : 0.5 * ((double)k[0].c[a] + k[1].c[a]);
        n->c[a] = (float)c[a];
        mo->m[a] = km[0].m[a] + km[1].m[a];
    }
    double r = 0;
    for (int h = 0; h < 2; h++) {
        double d2 = 0;
        for (int a = 0; a < 3; a++) d2 += ((double)k[h].c[a] - n->c[a]) * ((double)k[h].c[a] - n->c[a]);
        double rh = sqrt(d2) + k[h].r;
        r = rh > r ? rh : r;
        for (int i = 0; i < 3; i++)
            for (int j = 0; j < 3; j++)
                mo->P[3 * i + j] += (float)((double)km[h].P[3 * i + j] +
                                            (double)km[h].m[i] * ((double)k[h].c[j] - n->c[j]));
    }
    n->area = (float)area;
    n->r = (float)(r * (1 + 1e-6));
}

/* Node ni over ids[lo, hi); its children take the next free slots. */
static void build_node(builder *b, uint32_t ni, uint32_t lo, uint32_t hi)
{
    mesh_vox_beat(b->pulse, (hi - lo) / 4 + 1); /* the build is not abandoned: a tile needs it */
    wnode *n = &b->t->nodes[ni];
    memset(n, 0, sizeof *n);
    memset(&b->t->mom[ni], 0, sizeof b->t->mom[ni]);
    if (hi - lo <= LEAF) {
        n->first = lo, n->count = hi - lo;
        make_leaf(b, n, &b->t->mom[ni]);
        return;
    }
    double blo[3] = {INFINITY, INFINITY, INFINITY}, bhi[3] = {-INFINITY, -INFINITY, -INFINITY};
    for (uint32_t k = lo; k < hi; k++)
        for (int a = 0; a < 3; a++) {
            double v = b->cen[b->ids[k]][a];
            blo[a] = v < blo[a] ? v : blo[a];
            bhi[a] = v > bhi[a] ? v : bhi[a];
        }
    int axis = 0;
    for (int a = 1; a < 3; a++)
        if (bhi[a] - blo[a] > bhi[axis] - blo[axis]) axis = a;
    uint32_t mid = lo + (hi - lo) / 2, kid = b->t->n_nodes;
    select_kth(b, lo, hi, mid, axis);
    b->t->n_nodes += 2;
    n->first = kid;
    build_node(b, kid, lo, mid);
    build_node(b, kid + 1, mid, hi);
    n = &b->t->nodes[ni];
    inner_moments(n, &b->t->mom[ni], &b->t->nodes[kid], &b->t->mom[kid]);
}

int mesh_vox_wtree_make(const mesh *m, const grid_spec *g, const double (*tri)[3][3], uint32_t n,
                  mesh_vox_pulse *pulse, mesh_vox_wtree **out)
{
    *out = NULL;
    if (m) n = m->n_triangles;
    if (!n) return -EINVAL;
    mesh_vox_wtree *t = calloc(1, sizeof *t);
    builder b = {m, g, tri, malloc((size_t)n * sizeof *b.cen), malloc((size_t)n * sizeof *b.ids),
                 t, pulse};
    if (t) {
        /* 2n nodes and one before node 0, so that node 1 starts a line */
        size_t bytes = (2 * (size_t)n + 2) * sizeof *t->nodes;
        t->block = aligned_alloc(64, (bytes + 63) / 64 * 64);
        t->nodes = t->block ? (wnode *)t->block + 1 : NULL;
        t->mom = malloc(2 * (size_t)n * sizeof *t->mom);
        t->tri = malloc((size_t)n * sizeof *t->tri);
        t->tdip = m ? NULL : malloc((size_t)n * sizeof *t->tdip);
    }
    if (!t || !b.cen || !b.ids || !t->nodes || !t->mom || !t->tri || (!m && !t->tdip)) {
        free(b.cen), free(b.ids);
        mesh_vox_wtree_free(t);
        return -ENOMEM;
    }
    for (uint32_t i = 0; i < n; i++) {
        double p[3][3];
        tri_voxels(&b, i, p);
        for (int a = 0; a < 3; a++) b.cen[i][a] = (p[0][a] + p[1][a] + p[2][a]) / 3;
        b.ids[i] = i;
    }
    t->n_nodes = 1;
    build_node(&b, 0, 0, n);
    free(b.cen), free(b.ids);
    *out = t;
    return 0;
}

void mesh_vox_wtree_free(mesh_vox_wtree *t)
{
    if (!t) return;
    free(t->block);
    free(t->mom);
    free(t->tri);
    free(t->tdip);
    free(t);
}

/* ---- queries ---- */

static inline const wmom *mom_of(const mesh_vox_wtree *t, const wnode *n)
{
    return &t->mom[n - t->nodes];
}

/* The order-2 expansion of n at p: 4 pi w; R2 = |c - p|^2. */
static double expand(const wmom *n, const double d[3], double R2)
{
    double iR = 1 / sqrt(R2), iR3 = iR * iR * iR;
    double md = n->m[0] * d[0] + n->m[1] * d[1] + n->m[2] * d[2];
    double tr = (double)n->P[0] + n->P[4] + n->P[8];
    double dPd = 0;
    for (int i = 0; i < 3; i++)
        dPd += d[i] * (n->P[3 * i] * d[0] + n->P[3 * i + 1] * d[1] + n->P[3 * i + 2] * d[2]);
    return (md + tr) * iR3 - 3 * dPd * iR3 * iR * iR;
}

/* The solid angle of triangle v (9 floats) seen from p, over 2
 * (mesh_vox_half_solid_angle: Van Oosterom and Strackee's formula). */
static double tri_half_angle(const float *v, const double p[3])
{
    double a[3], b[3], c[3];
    for (int i = 0; i < 3; i++) a[i] = v[i] - p[i], b[i] = v[3 + i] - p[i], c[i] = v[6 + i] - p[i];
    return mesh_vox_half_solid_angle(a, b, c);
}

double mesh_vox_wind_point(const mesh_vox_wtree *t, const double p[3], double beta, uint32_t *work)
{
    uint32_t stack[128], sp = 0, visits = 0;
    double w = 0, b2 = beta * beta;
    stack[sp++] = 0;
    while (sp) {
        const wnode *n = &t->nodes[stack[--sp]];
        double d[3] = {n->c[0] - p[0], n->c[1] - p[1], n->c[2] - p[2]};
        double R2 = d[0] * d[0] + d[1] * d[1] + d[2] * d[2];
        visits++;
        if (R2 > b2 * n->r * n->r) {
            w += expand(mom_of(t, n), d, R2);
        } else if (n->count) {
            double q[3] = {-d[0], -d[1], -d[2]}; /* p from the leaf's centre */
            for (uint32_t k = 0; k < n->count; k++) w += 2 * tri_half_angle(t->tri[n->first + k], q);
        } else {
            stack[sp++] = n->first + 1;
            stack[sp++] = n->first;
        }
    }
    if (work) *work += visits;
    return w / (4 * M_PI);
}

/* Whether p (relative to the leaf's centre) lies within near of triangle
 * v's plane and of its vertices' ball: a point where the sign of the
 * angle may differ from the raster's side of the triangle. */
static bool near_tri(const float *v, const double q[3], double near)
{
    double e1[3], e2[3], c[3], r2 = 0, d2 = 0;
    for (int i = 0; i < 3; i++) e1[i] = (double)v[3 + i] - v[i], e2[i] = (double)v[6 + i] - v[i];
    double nx = e1[1] * e2[2] - e1[2] * e2[1], ny = e1[2] * e2[0] - e1[0] * e2[2],
           nz = e1[0] * e2[1] - e1[1] * e2[0];
    double h = nx * (q[0] - v[0]) + ny * (q[1] - v[1]) + nz * (q[2] - v[2]);
    if (h * h > near * near * (nx * nx + ny * ny + nz * nz)) return false; /* off its plane */
    for (int i = 0; i < 3; i++) {
        c[i] = ((double)v[i] + v[3 + i] + v[6 + i]) / 3;
        d2 += (q[i] - c[i]) * (q[i] - c[i]);
    }
    for (int j = 0; j < 3; j++) {
        double s = 0;
        for (int i = 0; i < 3; i++) s += (v[3 * j + i] - c[i]) * (v[3 * j + i] - c[i]);
        r2 = s > r2 ? s : r2;
    }
    double r = sqrt(r2) + near;
    return d2 <= r * r;
}

#define NEAR_REACH 3.0 /* a near list takes the triangles within this times
                          (rho + 1 voxel) of a cell's ball */
static double dot3(const double a[3], const double b[3])
{
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}

double mesh_vox_tri_dist(const double v[3][3], const double p[3])
{
    /* Ericson's closest point, "Real-Time Collision Detection" 5.1.5: the
     * Voronoi regions of the vertices, edges and face in turn */
    double ab[3], ac[3], ap[3], bp[3], cp[3], q[3];
    for (int i = 0; i < 3; i++) {
        ab[i] = v[1][i] - v[0][i], ac[i] = v[2][i] - v[0][i];
        ap[i] = p[i] - v[0][i], bp[i] = p[i] - v[1][i], cp[i] = p[i] - v[2][i];
    }
    double d1 = dot3(ab, ap), d2 = dot3(ac, ap), d3 = dot3(ab, bp), d4 = dot3(ac, bp);
    double d5 = dot3(ab, cp), d6 = dot3(ac, cp), s = 0, t = 0;
    double va = d3 * d6 - d5 * d4, vb = d5 * d2 - d1 * d6, vc = d1 * d4 - d3 * d2;
    if (d1 <= 0 && d2 <= 0) s = 0, t = 0;
    else if (d3 >= 0 && d4 <= d3) s = 1, t = 0;
    else if (d6 >= 0 && d5 <= d6) s = 0, t = 1;
    else if (vc <= 0 && d1 >= 0 && d3 <= 0) s = d1 / (d1 - d3), t = 0;
    else if (vb <= 0 && d2 >= 0 && d6 <= 0) s = 0, t = d2 / (d2 - d6);
    else if (va <= 0 && d4 - d3 >= 0 && d5 - d6 >= 0) {
        t = (d4 - d3) / ((d4 - d3) + (d5 - d6));
        s = 1 - t;
    } else {
        double den = va + vb + vc;
        s = vb / den, t = vc / den;
    }
    for (int i = 0; i < 3; i++) q[i] = v[0][i] + s * ab[i] + t * ac[i] - p[i];
    return sqrt(dot3(q, q));
}

/* The distance from p to triangle v (9 floats). */
static double tri_dist(const float *v, const double p[3])
{
    double d[3][3];
    for (int i = 0; i < 9; i++) d[i / 3][i % 3] = v[i];
    return mesh_vox_tri_dist((const double (*)[3])d, p);
}

/* A query's sums: 4 pi times the value w4 of the nodes taken and the
 * bound e4 of its error over the ball, their limits tol4 and e4max. */
typedef struct {
    double w4, e4, tol4, e4max;
} wsum;

/* Leaf n's triangles at the centre b of a cell of half-diagonal rho (q):
 * their exact angles into sum->w4, bound (2) into sum->e4; a triangle
 * that comes within 2 rho of b goes to the near list instead when there
 * is one (false when it is full), else within rho: false (no bound). */
static bool leaf_cell(const mesh_vox_wtree *t, const wnode *n, const mesh_vox_wball *q, mesh_vox_near *near,
                      wsum *sum)
{
    const double *bw = q->b, rho = q->rho;
    double b[3] = {bw[0] - n->c[0], bw[1] - n->c[1], bw[2] - n->c[2]}; /* from its centre */
    for (uint32_t k = 0; k < n->count; k++) {
        const float *v = t->tri[n->first + k];
        double c[3], r2 = 0, a = 0, e1[3], e2[3];
        for (int i = 0; i < 3; i++) {
            c[i] = ((double)v[i] + v[3 + i] + v[6 + i]) / 3;
            e1[i] = (double)v[3 + i] - v[i], e2[i] = (double)v[6 + i] - v[i];
        }
        for (int j = 0; j < 3; j++) {
            double s = 0;
            for (int i = 0; i < 3; i++) s += (v[3 * j + i] - c[i]) * (v[3 * j + i] - c[i]);
            r2 = s > r2 ? s : r2;
        }
        double x = e1[1] * e2[2] - e1[2] * e2[1], y = e1[2] * e2[0] - e1[0] * e2[2],
               z = e1[0] * e2[1] - e1[1] * e2[0];
        a = 0.5 * sqrt(x * x + y * y + z * z);
        double R = sqrt((c[0] - b[0]) * (c[0] - b[0]) + (c[1] - b[1]) * (c[1] - b[1]) +
                        (c[2] - b[2]) * (c[2] - b[2]));
        double dmin = R - sqrt(r2) * (1 + 1e-6) - rho, reach = NEAR_REACH * (rho + 1);
        if (near && dmin <= reach) /* the ball says near: the triangle itself */
            dmin = tri_dist(v, b) * (1 - 1e-9) - 1e-9 - rho;
        if (near && dmin <= reach) {
            if (near->n == MESH_VOX_NEAR_MAX) return false;
            near->tri[near->n] = n->first + k;
            near->leaf[near->n++] = (uint32_t)(n - t->nodes);
            continue;
        }
        if (dmin <= 0) return false;
        sum->w4 += 2 * tri_half_angle(v, b);
        /* the kernel's gradient is at most 2 / d^3, which over the
         * triangle sums to at most 2 a / d^3 and over its whole plane to
         * 4 pi / d */
        double g = 2 * a / (dmin * dmin * dmin);
        sum->e4 += rho * (g < 4 * M_PI / dmin ? g : 4 * M_PI / dmin);
    }
    return true;
}

double mesh_vox_wind_near(const mesh_vox_wtree *t, const mesh_vox_near *near, const double p[3], double close,
                    bool *is_close)
{
    mesh_vox_tris s = {near->tri, near->leaf, near->n};
    return mesh_vox_wind_tris(t, &s, p, close, is_close);
}

double mesh_vox_wind_tris(const mesh_vox_wtree *t, const mesh_vox_tris *s, const double p[3], double close,
                          bool *is_close)
{
    double w4 = 0;
    for (uint32_t k = 0; k < s->n; k++) {
        const wnode *n = &t->nodes[s->leaf[k]];
        const float *v = t->tri[s->tri[k]];
        double q[3] = {p[0] - n->c[0], p[1] - n->c[1], p[2] - n->c[2]};
        *is_close |= near_tri(v, q, close);
        w4 += 2 * tri_half_angle(v, q);
    }
    return w4 / (4 * M_PI);
}

/* What a walk from the root does at node n: 0 took it (into s), 1 opens
 * it, -1 stops (no bound). */
typedef int (*wvisit)(const mesh_vox_wtree *t, const wnode *n, const mesh_vox_wball *q, mesh_vox_near *near,
                      wsum *s);

/* The walk of mesh_vox_wind_cell and mesh_vox_wind_mag (inlined with
 * each visit): false when a visit stops it or s->e4 passes s->e4max. */
static inline bool walk(const mesh_vox_wtree *t, const mesh_vox_wball *q, mesh_vox_near *near, wsum *s,
                        wvisit visit, uint32_t *work)
{
    uint32_t stack[128], sp = 0, visits = 0;
    bool ok = true;
    stack[sp++] = 0;
    while (sp && ok) {
        const wnode *n = &t->nodes[stack[--sp]];
        visits++;
        int r = visit(t, n, q, near, s);
        if (r < 0) {
            ok = false;
        } else if (r == 1) {
            stack[sp++] = n->first + 1;
            stack[sp++] = n->first;
        }
        if (s->e4 > s->e4max) ok = false;
    }
    if (work) *work += visits;
    return ok;
}

static int cell_visit(const mesh_vox_wtree *t, const wnode *n, const mesh_vox_wball *q, mesh_vox_near *near,
                      wsum *s)
{
    double d[3] = {n->c[0] - q->b[0], n->c[1] - q->b[1], n->c[2] - q->b[2]};
    double R2 = d[0] * d[0] + d[1] * d[1] + d[2] * d[2], rr = n->r + q->rho;
    bool far = R2 > 4 * rr * rr; /* beta 2; tol infinite: the old rule, beta alone */
    double e = 0;
    if (far) {
        double R = sqrt(R2), sr = R - n->r, f = R - rr;
        e = n->area * (3.0 * n->r * n->r / (sr * sr * sr * sr) + 2 * q->rho / (f * f * f));
    }
    if (far && e <= s->tol4) {
        s->w4 += expand(mom_of(t, n), d, R2);
        s->e4 += e;
        return 0;
    }
    if (n->count) return leaf_cell(t, n, q, near, s) ? 0 : -1;
    return 1;
}

bool mesh_vox_wind_cell(const mesh_vox_wtree *t, const mesh_vox_wball *q, mesh_vox_near *near, double *w,
                        double *err, uint32_t *work)
{
    if (near) near->n = 0;
    wsum s = {0, 0, q->tol * 4 * M_PI, q->emax * 4 * M_PI};
    bool ok = walk(t, q, near, &s, cell_visit, work);
    *w = s.w4 / (4 * M_PI);
    *err = s.e4 / (4 * M_PI) + 1e-9; /* and the rounding of the sums */
    return ok;
}

static int mag_visit(const mesh_vox_wtree *t, const wnode *n, const mesh_vox_wball *q, mesh_vox_near *near,
                     wsum *s)
{
    (void)t, (void)near;
    double d[3] = {n->c[0] - q->b[0], n->c[1] - q->b[1], n->c[2] - q->b[2]};
    double f = sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]) - n->r - q->rho;
    /* a triangle of area a at distance f subtends at most a / f^2 */
    double e = f > 0 ? n->area / (f * f) : INFINITY;
    if (e <= s->tol4) {
        s->e4 += e;
        return 0;
    }
    if (n->count) return f > 0 && (s->e4 += e) <= s->e4max ? 0 : -1;
    return 1;
}

bool mesh_vox_wind_mag(const mesh_vox_wtree *t, const mesh_vox_wball *q, double *bound, uint32_t *work)
{
    wsum s = {0, 0, q->tol * 4 * M_PI, q->emax * 4 * M_PI};
    bool ok = walk(t, q, NULL, &s, mag_visit, work);
    *bound = s.e4 / (4 * M_PI) + 1e-9;
    return ok;
}

/* ---- the far field handed down a cell's halves ---- */

/* Triangle k of leaf l at the cell q (b, rho): its dipole (where the
 * triangle is far: a node of one triangle, P = 0 about its centroid) or
 * its exact angle at b into o->w4 and the bound over the cell into o->e4
 * (true), or false: its bound passes tol4 (the cell's halves take it), or
 * (rho = 0) b lies within CLOSE_BALL of its ball (mesh_vox_wind_tris
 * decides whether b is too close). */
#define CLOSE_BALL 2e-3 /* voxels: more than mesh_wcap.c's NEAR */
static bool down_tri(const mesh_vox_wtree *t, uint32_t l, uint32_t k, const mesh_vox_wball *q,
                     mesh_vox_wlist *o)
{
    const wnode *n = &t->nodes[l];
    const double *bw = q->b, rho = q->rho, tol4 = q->tol * 4 * M_PI;
    const double *x = t->tdip[k]; /* centroid, radius, area vector, area */
    double d[3] = {x[0] - (bw[0] - n->c[0]), x[1] - (bw[1] - n->c[1]), x[2] - (bw[2] - n->c[2])};
    double R = sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]), r = x[3], a = x[7];
    double dmin = R - r - rho;
    if (rho == 0 && dmin <= CLOSE_BALL) return false;
    if (R > 2 * (r + rho)) {
        double s = R - r;
        double e = a * (3 * r * r / (s * s * s * s) + 2 * rho / (dmin * dmin * dmin));
        if (e <= tol4) {
            o->w4 += (x[4] * d[0] + x[5] * d[1] + x[6] * d[2]) / (R * R * R);
            o->e4 += e;
            return true;
        }
    }
    double b[3] = {bw[0] - n->c[0], bw[1] - n->c[1], bw[2] - n->c[2]};
    if (dmin <= 0) dmin = tri_dist(t->tri[k], b) * (1 - 1e-9) - 1e-9 - rho;
    if (dmin <= 0) return false;
    double g = 2 * a / (dmin * dmin * dmin); /* leaf_cell's bound */
    double e = rho * (g < 4 * M_PI / dmin ? g : 4 * M_PI / dmin);
    if (e > tol4) return false;
    o->w4 += 2 * tri_half_angle(t->tri[k], b);
    o->e4 += e;
    return true;
}

/* Node ni at the cell q (b, rho): taken whole into o (by its expansion,
 * or by its magnitude: area / f^2 with value 0), else 1: open it, 2: hand
 * it down. */
static int down_node(const mesh_vox_wtree *t, const wnode *n, const mesh_vox_wball *q,
                     mesh_vox_wlist *o)
{
    const double *b = q->b, rho = q->rho, tol4 = q->tol * 4 * M_PI;
    double d[3] = {n->c[0] - b[0], n->c[1] - b[1], n->c[2] - b[2]};
    double R2 = d[0] * d[0] + d[1] * d[1] + d[2] * d[2], rr = n->r + rho;
    if (R2 > 4 * rr * rr) { /* beta 2, as mesh_vox_wind_cell */
        double R = sqrt(R2), s = R - n->r, f = R - rr;
        double e = n->area * (3.0 * n->r * n->r / (s * s * s * s) + 2 * rho / (f * f * f));
        if (e <= tol4) {
            o->w4 += expand(mom_of(t, n), d, R2);
            o->e4 += e;
            return 0;
        }
        double m = n->area / (f * f); /* a surface of area a beyond f subtends at most a / f^2 */
        if (m <= tol4) {
            o->e4 += m;
            return 0;
        }
    }
    return rho > 0 && n->r <= rho ? 2 : 1;
}

static bool down_push(mesh_vox_wlist *o, uint32_t node, uint32_t tri)
{
    if (tri == UINT32_MAX) {
        if (o->n_node == o->cap) return false;
        o->node[o->n_node++] = node;
        return true;
    }
    if (o->n_tri == o->cap) return false;
    o->tri[o->n_tri] = tri;
    o->leaf[o->n_tri++] = node;
    return true;
}

bool mesh_vox_wind_down(const mesh_vox_wtree *t, const mesh_vox_wlist *in, const mesh_vox_wball *q,
                        mesh_vox_wlist *out, uint32_t *work)
{
    uint32_t stack[128], sp = 0, visits = 0;
    double e4max = q->emax * 4 * M_PI;
    out->n_node = out->n_tri = 0;
    out->w4 = in->w4, out->e4 = in->e4;
    bool ok = true;
    for (uint32_t k = 0; k < in->n_tri && ok; k++)
        if (!down_tri(t, in->leaf[k], in->tri[k], q, out))
            ok = down_push(out, in->leaf[k], in->tri[k]);
    for (uint32_t i = 0; i < in->n_node && ok; i++) {
        stack[sp++] = in->node[i];
        while (sp && ok) {
            uint32_t ni = stack[--sp];
            const wnode *n = &t->nodes[ni];
            visits++;
            int r = down_node(t, n, q, out);
            if (r == 2) {
                ok = down_push(out, ni, UINT32_MAX);
            } else if (r == 1 && n->count) {
                for (uint32_t k = n->first; k < n->first + n->count && ok; k++)
                    if (!down_tri(t, ni, k, q, out)) ok = down_push(out, ni, k);
            } else if (r == 1) {
                stack[sp++] = n->first + 1;
                stack[sp++] = n->first;
            }
        }
        if (out->e4 > e4max) ok = false;
    }
    if (work) *work += visits + in->n_tri;
    return ok && out->e4 <= e4max;
}

/* ---- a block's samples ---- */

#define TOP 32u       /* the largest cell tried, samples a side (divides 64) */
#define CELL_MIN 4u   /* samples to decide that make a cell worth a query */
#define BETA1 2.0     /* the first point query's opening ratio ... */
#define BAND1 0.05    /* ... decides where |w| is farther from 1/2 */
#define BETA2 6.0
#define BAND2 0.001   /* else the exact sum over every triangle */

typedef struct {
    const mesh_vox_frame *f;
    const mesh_vox_block *b;
    const uint64_t *dis;
    uint64_t *bits;
    double q[64][3];  /* the exact sum's points, sample units ... */
    size_t at[64];    /* ... and their bits (word * 64 + bit) */
    unsigned n;
} wblock;

static void cell_fill(wblock *w, const uint32_t lo[3], const uint32_t hi[3], bool inside)
{
    mesh_vox_decide d = {w->b, w->dis, w->bits, NULL, NULL};
    mesh_vox_cell_decide(&d, lo, hi, inside);
}

static void set_bit(wblock *w, size_t at, bool inside)
{
    uint64_t bit = 1ull << (at & 63);
    w->bits[at / 64] = inside ? w->bits[at / 64] | bit : w->bits[at / 64] & ~bit;
}

/* The exact sum for the points gathered (the oracle's own function). */
static void flush_exact(wblock *w)
{
    double wn[64];
    if (!w->n) return;
    mesh_vox_winding_many(w->f, (const double (*)[3])w->q, w->n, wn);
    for (unsigned k = 0; k < w->n; k++) set_bit(w, w->at[k], fabs(wn[k]) >= 0.5);
    w->n = 0;
}

/* Sample (x, y, z) of the block: the tree twice, then the exact sum. */
static void point(wblock *w, const mesh_vox_wtree *t, const uint32_t s[3])
{
    const mesh_vox_frame *f = w->f;
    double q[3], p[3];
    uint32_t work = 0;
    for (int a = 0; a < 3; a++) {
        q[a] = (double)(w->b->s0[a] + (int64_t)s[a]) + 0.5;
        p[a] = q[a] / f->K;
    }
    size_t at = mesh_vox_word(w->b, s[0], s[1], s[2]) * 64 + (s[0] & 63);
    double v = fabs(mesh_vox_wind_point(t, p, BETA1, &work));
    if (fabs(v - 0.5) <= BAND1) v = fabs(mesh_vox_wind_point(t, p, BETA2, &work));
    mesh_vox_beat(f->pulse, work);
    if (fabs(v - 0.5) > BAND2) {
        set_bit(w, at, v > 0.5);
        return;
    }
    memcpy(w->q[w->n], q, sizeof q);
    w->at[w->n++] = at;
    if (w->n == 64) flush_exact(w);
}

/* Cell [lo, hi): decided whole by one query when the bound allows, else
 * its eight halves. */
static void cell(wblock *w, const mesh_vox_wtree *t, const uint32_t lo[3], const uint32_t hi[3])
{
    uint64_t n = mesh_vox_cell_count(w->b, w->dis, lo, hi);
    if (!n || (w->f->pulse && w->f->pulse->stop)) return;
    uint32_t ext[3] = {hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]};
    if (ext[0] == 1 && ext[1] == 1 && ext[2] == 1) {
        point(w, t, lo);
        return;
    }
    if (n >= CELL_MIN) {
        double K = w->f->K, b[3], r2 = 0, v, e;
        uint32_t work = 0;
        for (int a = 0; a < 3; a++) {
            b[a] = ((double)w->b->s0[a] + 0.5 * ((double)lo[a] + hi[a])) / K;
            r2 += 0.25 * (double)(ext[a] - 1) * (ext[a] - 1);
        }
        mesh_vox_wball qb = {{b[0], b[1], b[2]}, sqrt(r2) / K * (1 + 1e-9), INFINITY, 0.5};
        bool ok = mesh_vox_wind_cell(t, &qb, NULL, &v, &e, &work);
        mesh_vox_beat(w->f->pulse, work);
        v = fabs(v);
        if (ok && (v - e > 0.5 || v + e < 0.5)) {
            cell_fill(w, lo, hi, v > 0.5);
            return;
        }
    }
    for (int k = 0; k < 8; k++) {
        uint32_t clo[3], chi[3];
        if (mesh_vox_half(lo, hi, k, clo, chi)) cell(w, t, clo, chi);
    }
}

void mesh_vox_wind_block(const mesh_vox_frame *f, const mesh_vox_wtree *t, const mesh_vox_block *b, const uint64_t *dis,
                   uint64_t *bits)
{
    wblock w = {.f = f, .b = b, .dis = dis, .bits = bits};
    uint32_t lo[3] = {0, 0, 0}, hi[3] = {0, 0, 0};
    while (mesh_vox_top_next(b, TOP, lo, hi)) cell(&w, t, lo, hi);
    flush_exact(&w);
}

/* ---- the exact sum (the fallback near 1/2, and --repair winding without the tree) ---- */

/* The solid angle of triangle (a, b, c) seen from the origin, over 2:
 * atan2 of Van Oosterom and Strackee's formula; for the small angles of
 * the many far triangles, the series of atan (to t^7: below 1e-17 when
 * |t| < 1/64) instead of atan2. */
/* Van Oosterom and Strackee's half solid angle, and its parts. */
static inline double half_angle(const double a[3], const double b[3], const double c[3],
                                double *det_out, double *den_out, double *l_out)
{
    double la = sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2]);
    double lb = sqrt(b[0] * b[0] + b[1] * b[1] + b[2] * b[2]);
    double lc = sqrt(c[0] * c[0] + c[1] * c[1] + c[2] * c[2]);
    double det = a[0] * (b[1] * c[2] - b[2] * c[1]) -
                 a[1] * (b[0] * c[2] - b[2] * c[0]) +
                 a[2] * (b[0] * c[1] - b[1] * c[0]);
    double ab = a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
    double bc = b[0] * c[0] + b[1] * c[1] + b[2] * c[2];
    double ca = c[0] * a[0] + c[1] * a[1] + c[2] * a[2];
    double den = la * lb * lc + ab * lc + bc * la + ca * lb;
    *det_out = det, *den_out = den, *l_out = la * lb * lc;
    if (den > 0 && fabs(det) < den * (1.0 / 64)) {
        double t = det / den, t2 = t * t;
        return t * (1 - t2 * (1.0 / 3 - t2 * (1.0 / 5 - t2 * (1.0 / 7))));
    }
    return atan2(det, den);
}

double mesh_vox_half_solid_angle(const double a[3], const double b[3], const double c[3])
{
    double det, den, l;
    return half_angle(a, b, c, &det, &den, &l);
}

double mesh_vox_half_solid_angle_parts(const double a[3], const double b[3], const double c[3],
                                       double *det, double *den, double *l)
{
    return half_angle(a, b, c, det, den, l);
}

void mesh_vox_winding_many(const mesh_vox_frame *f, const double (*q)[3], unsigned n, double *w)
{
    const mesh *m = f->m;
    double s = f->scale / (double)MESH_VOX_L;
    for (unsigned k = 0; k < n; k++) w[k] = 0;
    for (uint32_t t = 0; t < m->n_triangles; t++) {
        if (mesh_vox_beat(f->pulse, n)) return; /* the tile is abandoned */
        double p[3][3];
        for (int i = 0; i < 3; i++) {
            const float *v = m->vertices[m->triangles[t][i]];
            for (int a = 0; a < 3; a++) p[i][a] = ((double)v[a] - f->lo[a]) * s;
        }
        for (unsigned k = 0; k < n; k++) {
            double r[3][3];
            for (int i = 0; i < 3; i++)
                for (int a = 0; a < 3; a++) r[i][a] = p[i][a] - q[k][a];
            w[k] += mesh_vox_half_solid_angle(r[0], r[1], r[2]);
        }
    }
    for (unsigned k = 0; k < n; k++) w[k] /= 2.0 * M_PI; /* solid angles / (4 pi) */
}
