/* One task: a brick's samples gathered with their apron, its cells cut by
 * the case table, its vertices keyed by their lattice edges (iso.h). */
#include <errno.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "iso.h"
#include "voxel.h"

typedef struct {
    void *p;
    size_t n, cap, size;
} vec;

struct iso_work {
    uint32_t B, S;          /* brick, samples per axis (B + 1) */
    uint8_t *val;           /* S^3 sample bytes */
    uint32_t *word;         /* S^3 channel-3 voxels (normals), or NULL */
    float *dist;            /* S^3 channel-4 distances (NaN: empty), or NULL */
    int32_t *map;           /* S^3 x 3 edges: an owned vertex's index, -2 - k for
                               ext[k] (another task's), -1 none yet */
    uint8_t *row;           /* S^2 rows of S samples (y, z): ROW_OUT, ROW_IN, ROW_MIXED */
    uint32_t *blk;          /* adaptive: 3 x S block coordinates */
    uint8_t *same;          /* adaptive: S^3 flags, block of the task's level */
    vec keys, pos, nrm, cpos, cnrm, tri, ext;
    vec touched;            /* the map entries set by the running task */
    /* the running task */
    const iso_params *p;
    uint32_t level, b[3], W[3];
    double vs[3];
};

static int vec_grow(vec *v, size_t more)
{
    if (v->n + more <= v->cap) return 0;
    size_t cap = v->cap ? v->cap : 256;
    while (cap < v->n + more) cap *= 2;
    void *q = realloc(v->p, cap * v->size);
    if (!q) return -ENOMEM;
    v->p = q;
    v->cap = cap;
    return 0;
}

int iso_work_new(const iso_params *p, iso_work **out)
{
    iso_work *w = calloc(1, sizeof *w);
    if (!w) return -ENOMEM;
    w->B = p->brick;
    w->S = p->brick + 1;
    size_t n = (size_t)w->S * w->S * w->S;
    w->val = malloc(n);
    w->map = malloc(n * 3 * sizeof *w->map);
    if (w->map) memset(w->map, 0xff, n * 3 * sizeof *w->map); /* kept so: see forget() */
    w->word = p->normals ? malloc(n * sizeof *w->word) : NULL;
    w->dist = p->distance ? malloc(n * sizeof *w->dist) : NULL;
    w->row = malloc((size_t)w->S * w->S);
    w->blk = malloc(3 * (size_t)w->S * sizeof *w->blk);
    w->same = malloc(n);
    w->keys.size = w->ext.size = 8;
    w->pos.size = w->nrm.size = w->cpos.size = w->cnrm.size = 3 * sizeof(float);
    w->tri.size = 3 * sizeof(uint32_t);
    w->touched.size = sizeof(size_t);
    if (!w->val || !w->map || !w->row || !w->blk || !w->same || (p->normals && !w->word) ||
        (p->distance && !w->dist)) {
        iso_work_free(w);
        return -ENOMEM;
    }
    *out = w;
    return 0;
}

void iso_work_free(iso_work *w)
{
    if (!w) return;
    free(w->val);
    free(w->word);
    free(w->dist);
    free(w->map);
    free(w->row);
    free(w->blk);
    free(w->same);
    vec *v[] = {&w->keys, &w->pos, &w->nrm, &w->cpos, &w->cnrm, &w->tri, &w->ext, &w->touched};
    for (size_t i = 0; i < sizeof v / sizeof *v; i++) free(v[i]->p);
    free(w);
}

/* ---- gathering ---- */

static inline size_t sidx(const iso_work *w, uint32_t x, uint32_t y, uint32_t z)
{
    return ((size_t)z * w->S + y) * w->S + x;
}


static const uint8_t *find_brick(const iso_input *in, uint64_t key, uint32_t bits, uint32_t B)
{
    uint64_t lo = 0, hi = in->n;
    while (lo < hi) {
        uint64_t mid = lo + (hi - lo) / 2;
        if (in->keys[mid] < key) lo = mid + 1;
        else hi = mid;
    }
    if (lo == in->n || in->keys[lo] != key) return NULL;
    size_t raw = (size_t)B * B * B * bits / 8;
    if (in->offs[lo] > in->raw_bytes || in->raw_bytes - in->offs[lo] < raw) return NULL;
    return in->raw + in->offs[lo];
}

/* The file brick fb of the task's level, NULL when empty or outside (or,
 * adaptive, in no block of this level): its samples read as 0. */
static const uint8_t *brick_at(iso_work *w, const iso_input *in, const int64_t fb[3])
{
    const iso_params *p = w->p;
    uint32_t side = 1u << (p->height - 1 - w->level), u[3];
    for (int a = 0; a < 3; a++) {
        if (fb[a] < 0 || fb[a] >= side) return NULL;
        u[a] = (uint32_t)fb[a];
    }
    uint64_t lin = ((uint64_t)u[2] * side + u[1]) * side + u[0];
    return find_brick(in, iso_brick_key(w->level, lin), p->bits, w->B);
}

/* Copy the voxels [v0, v0 + n) of raw brick r to the samples at s0; r
 * NULL: those samples are 0. */
static void copy_box(iso_work *w, const uint8_t *r, const uint32_t v0[3],
                     const uint32_t s0[3], const uint32_t n[3])
{
    uint32_t B = w->B, S = w->S, bits = w->p->bits;
    for (uint32_t z = 0; z < n[2]; z++)
        for (uint32_t y = 0; y < n[1]; y++) {
            size_t vi = ((size_t)(v0[2] + z) * B + v0[1] + y) * B + v0[0];
            size_t si = ((size_t)(s0[2] + z) * S + s0[1] + y) * S + s0[0];
            if (!r) {
                memset(w->val + si, 0, n[0]);
                if (w->word) memset(w->word + si, 0, n[0] * sizeof *w->word);
                for (uint32_t x = 0; w->dist && x < n[0]; x++) w->dist[si + x] = NAN;
            } else if (bits == 8) {
                memcpy(w->val + si, r + vi, n[0]);
            } else if (w->dist) {
                for (uint32_t x = 0; x < n[0]; x++) {
                    uint32_t v = vod_get32(r + 4 * (vi + x));
                    memcpy(&w->dist[si + x], &v, 4);
                    w->val[si + x] = v >> 31 ? 255 : 0; /* negative: inside */
                }
            } else if (bits == 1) {
                for (uint32_t x = 0; x < n[0]; x++)
                    w->val[si + x] = (r[(vi + x) >> 3] >> ((vi + x) & 7) & 1u) ? 255 : 0;
            } else {
                for (uint32_t x = 0; x < n[0]; x++) {
                    uint32_t v = vod_get32(r + 4 * (vi + x));
                    w->val[si + x] = (uint8_t)voxel_occupancy(v);
                    w->word[si + x] = v;
                }
            }
        }
}

/* Samples past the level's volume read 0 (the writer leaves them 0; a
 * file that does not is not believed). */
static void clip(iso_work *w)
{
    uint32_t S = w->S;
    for (int a = 0; a < 3; a++) {
        uint64_t lim = (uint64_t)w->p->dims[w->level][a] + 1 - (uint64_t)w->b[a] * w->B;
        for (uint32_t z = 0; lim < S && z < S; z++)
            for (uint32_t y = 0; y < S; y++)
                for (uint32_t x = 0; x < S; x++) {
                    uint32_t c[3] = {x, y, z};
                    if (c[a] < lim) continue;
                    size_t i = sidx(w, x, y, z);
                    w->val[i] = 0;
                    if (w->word) w->word[i] = 0;
                    if (w->dist) w->dist[i] = NAN;
                }
    }
}

/* Adaptive levels: the samples in blocks of another level read 0.  A
 * sample of level l covers 2^l level-0 voxels, all in one block (blocks
 * are at least 2^lod_top voxels); the task's samples span few blocks per
 * axis, whose levels are looked up once. */
static void mask_blocks(iso_work *w)
{
    const iso_params *p = w->p;
    uint32_t S = w->S, lo[3], nb[3], *blk[3] = {w->blk, w->blk + S, w->blk + 2 * S};
    for (int a = 0; a < 3; a++) {
        for (uint32_t i = 0; i < S; i++) {
            int64_t s = (int64_t)w->b[a] * w->B + i - 1; /* -1: read 0 anyway */
            blk[a][i] = s < 0 ? 0 : (uint32_t)(((uint64_t)s << w->level) / p->block);
        }
        lo[a] = blk[a][0];
        nb[a] = blk[a][S - 1] - lo[a] + 1;
    }
    uint8_t *same = w->same; /* nb[0] nb[1] nb[2] <= S^3 entries */
    uint32_t k[3];
    for (k[2] = 0; k[2] < nb[2]; k[2]++)
        for (k[1] = 0; k[1] < nb[1]; k[1]++)
            for (k[0] = 0; k[0] < nb[0]; k[0]++) {
                uint32_t b[3] = {lo[0] + k[0], lo[1] + k[1], lo[2] + k[2]};
                same[(k[2] * nb[1] + k[1]) * nb[0] + k[0]] = iso_block_level(p, b) == w->level;
            }
    for (uint32_t z = 0; z < S; z++)
        for (uint32_t y = 0; y < S; y++)
            for (uint32_t x = 0; x < S; x++) {
                size_t t = ((size_t)(blk[2][z] - lo[2]) * nb[1] + blk[1][y] - lo[1]) * nb[0] +
                           blk[0][x] - lo[0];
                if (same[t]) continue;
                size_t i = sidx(w, x, y, z);
                w->val[i] = 0;
                if (w->word) w->word[i] = 0;
                if (w->dist) w->dist[i] = NAN;
            }
}

/* The task's samples: local s on an axis is voxel b B - 1 + s of the
 * level; local 0 comes from file brick b - 1 (its last voxel), 1..B from
 * file brick b. */
static void gather(iso_work *w, const iso_input *in)
{
    for (uint32_t c = 0; c < 8; c++) { /* the 8 boxes cover every sample */
        int64_t fb[3];
        uint32_t v0[3], s0[3], cnt[3];
        for (int a = 0; a < 3; a++) {
            int hi = c >> a & 1u;
            fb[a] = (int64_t)w->b[a] - (hi ? 0 : 1);
            v0[a] = hi ? 0 : w->B - 1;
            s0[a] = hi ? 1 : 0;
            cnt[a] = hi ? w->B : 1;
        }
        copy_box(w, brick_at(w, in, fb), v0, s0, cnt);
    }
    clip(w);
    if (w->p->nradii) mask_blocks(w);
}

/* ---- vertices ---- */

/* The map is all -1 between tasks: a task notes each entry before it sets
 * it, and forget() puts them back, instead of clearing 3 S^3 entries per
 * task. */
static int remember(iso_work *w, size_t m)
{
    if (vec_grow(&w->touched, 1)) return -ENOMEM;
    ((size_t *)w->touched.p)[w->touched.n++] = m;
    return 0;
}

static void forget(iso_work *w)
{
    for (size_t i = 0; i < w->touched.n; i++) w->map[((size_t *)w->touched.p)[i]] = -1;
    w->touched.n = 0;
}

static uint64_t edge_key(const iso_work *w, const uint32_t l[3], uint32_t a)
{
    uint64_t u[3];
    for (int d = 0; d < 3; d++) u[d] = (uint64_t)w->b[d] * w->B + l[d];
    return iso_brick_key(w->level, ((u[2] * w->W[1] + u[1]) * w->W[0] + u[0]) * 4 + a);
}

/* Channel 4: where the line from distance a to b (of opposite signs, or
 * one NaN: an empty sample) is 0, kept off the samples by 2^-20 so that
 * no triangle is degenerate. */
static double distance_t(float a, float b)
{
    if (isnan(a) || isnan(b) || a == b) return 0.5;
    double t = (double)a / ((double)a - (double)b), e = 1.0 / (1 << 20);
    return t < e ? e : t > 1 - e ? 1 - e : t;
}

/* The crossing on the edge from local sample l along axis a: world
 * position and, with normals, the normal. */
static void edge_vertex(const iso_work *w, const uint32_t l[3], uint32_t a, float pos[3],
                        float nrm[3])
{
    uint32_t m[3] = {l[0], l[1], l[2]};
    m[a]++;
    size_t i0 = sidx(w, l[0], l[1], l[2]), i1 = sidx(w, m[0], m[1], m[2]);
    double va = w->val[i0], vb = w->val[i1];
    double t = ((double)w->p->iso + 0.5 - va) / (vb - va);
    if (w->dist) t = distance_t(w->dist[i0], w->dist[i1]);
    for (int d = 0; d < 3; d++) {
        double s = (double)w->b[d] * w->B + l[d] + (d == (int)a ? t : 0) - 1.0;
        pos[d] = (float)(w->p->origin[d] + (s + 0.5) * w->vs[d]);
    }
    if (!nrm) return;
    double n0[3] = {0, 0, 0}, n1[3] = {0, 0, 0}, s = 0;
    if (va > 0) voxel_unpack_normal(w->word[i0], n0);
    if (vb > 0) voxel_unpack_normal(w->word[i1], n1);
    double n[3];
    for (int d = 0; d < 3; d++) {
        n[d] = va * n0[d] + vb * n1[d];
        s += n[d] * n[d];
    }
    s = s > 0 ? 1.0 / sqrt(s) : 0;
    for (int d = 0; d < 3; d++) nrm[d] = (float)(n[d] * s);
}

static int crossing(const iso_work *w, size_t i0, size_t i1)
{
    uint32_t iso = w->p->iso;
    return (w->val[i0] > iso) != (w->val[i1] > iso);
}

enum { ROW_OUT = 0, ROW_IN = 1, ROW_MIXED = 2 };

/* Each row of samples: all outside, all inside, or both, so that the
 * passes skip the rows (most of them) where nothing can cross. */
static int classify_rows(iso_work *w)
{
    uint32_t S = w->S, iso = w->p->iso, any = 0;
    for (size_t r = 0; r < (size_t)S * S; r++) {
        const uint8_t *v = w->val + r * S;
        uint32_t in = 0;
        for (uint32_t x = 0; x < S; x++) in += v[x] > iso;
        w->row[r] = in == 0 ? ROW_OUT : in == S ? ROW_IN : ROW_MIXED;
        any |= 1u << w->row[r];
    }
    return any != 1u << ROW_OUT && any != 1u << ROW_IN; /* anything to cut? */
}

/* Can an edge between rows r0 and r1 cross? */
static int rows_differ(const iso_work *w, size_t r0, size_t r1)
{
    return w->row[r0] == ROW_MIXED || w->row[r0] != w->row[r1];
}

static int add_vertex(iso_work *w, uint32_t x, uint32_t y, uint32_t z, uint32_t a)
{
    size_t m = sidx(w, x, y, z) * 3 + a;
    if (vec_grow(&w->keys, 1) || vec_grow(&w->pos, 1) || (w->word && vec_grow(&w->nrm, 1)) ||
        remember(w, m))
        return -ENOMEM;
    uint32_t l[3] = {x, y, z};
    size_t k = w->keys.n++;
    ((uint64_t *)w->keys.p)[k] = edge_key(w, l, a);
    edge_vertex(w, l, a, (float *)w->pos.p + 3 * k, w->word ? (float *)w->nrm.p + 3 * k : NULL);
    if (w->word) w->nrm.n++;
    w->pos.n++;
    w->map[m] = (int32_t)k;
    return 0;
}

/* Pass 1: the vertices this task owns: the crossings on the three edges
 * leaving the low corner of each of its cells, in key order. */
static int own_vertices(iso_work *w, const uint32_t nc[3])
{
    uint32_t S = w->S;
    for (uint32_t z = 0; z < nc[2]; z++)
        for (uint32_t y = 0; y < nc[1]; y++) {
            size_t r = (size_t)z * S + y;
            int ax[3] = {w->row[r] == ROW_MIXED, rows_differ(w, r, r + 1),
                         rows_differ(w, r, r + S)};
            if (!ax[0] && !ax[1] && !ax[2]) continue;
            size_t step[3] = {1, S, (size_t)S * S};
            for (uint32_t x = 0; x < nc[0]; x++) {
                size_t i0 = sidx(w, x, y, z);
                for (uint32_t a = 0; a < 3; a++) {
                    if (!ax[a] || !crossing(w, i0, i0 + step[a])) continue;
                    int rc = add_vertex(w, x, y, z, a);
                    if (rc) return rc;
                }
            }
        }
    return 0;
}

/* The reference of slot e of the cell at local c: owned (pass 1 made it)
 * or another task's, by key. */
static int edge_ref(iso_work *w, const uint32_t c[3], uint32_t e, uint32_t *ref)
{
    uint32_t o = iso_edge_corner(e), a = iso_edge_axis(e), l[3];
    for (int d = 0; d < 3; d++) l[d] = c[d] + (o >> d & 1u);
    size_t m = sidx(w, l[0], l[1], l[2]) * 3 + a;
    if (w->map[m] >= 0) { /* owned */
        *ref = (uint32_t)w->map[m];
        return 0;
    }
    if (w->map[m] < -1) { /* another task's, met before: -2 - its index in ext */
        *ref = ISO_REF_EXT | (uint32_t)(-2 - w->map[m]);
        return 0;
    }
    if (l[0] < w->B && l[1] < w->B && l[2] < w->B) return -EINVAL; /* pass 1 missed it */
    if (vec_grow(&w->ext, 1) || remember(w, m)) return -ENOMEM;
    size_t k = w->ext.n++;
    ((uint64_t *)w->ext.p)[k] = edge_key(w, l, a);
    *ref = ISO_REF_EXT | (uint32_t)k;
    w->map[m] = -2 - (int32_t)k;
    return 0;
}

/* A centre vertex: the mean of its loop's crossings. */
static int centre(iso_work *w, const uint32_t c[3], const iso_case *cs, uint32_t k,
                  uint32_t *ref)
{
    if (vec_grow(&w->cpos, 1) || (w->word && vec_grow(&w->cnrm, 1))) return -ENOMEM;
    double s[3] = {0, 0, 0}, n[3] = {0, 0, 0};
    for (uint32_t i = 0; i < cs->loop_len[k]; i++) {
        uint32_t e = cs->loop[k][i], o = iso_edge_corner(e), l[3];
        for (int d = 0; d < 3; d++) l[d] = c[d] + (o >> d & 1u);
        float p[3], q[3];
        edge_vertex(w, l, iso_edge_axis(e), p, w->word ? q : NULL);
        for (int d = 0; d < 3; d++) {
            s[d] += p[d];
            if (w->word) n[d] += q[d];
        }
    }
    size_t j = w->cpos.n++;
    float *cp = (float *)w->cpos.p + 3 * j;
    for (int d = 0; d < 3; d++) cp[d] = (float)(s[d] / cs->loop_len[k]);
    if (w->word) {
        double len = sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
        float *cn = (float *)w->cnrm.p + 3 * w->cnrm.n++;
        for (int d = 0; d < 3; d++) cn[d] = (float)(len > 0 ? n[d] / len : 0);
    }
    *ref = ISO_REF_CENTRE | (uint32_t)j;
    return 0;
}

/* The inside bits of the four samples (x, y + j, z + k) of a column:
 * bit j + 2 k. */
static uint32_t column(const iso_work *w, size_t i)
{
    size_t S = w->S, SS = S * S;
    uint32_t iso = w->p->iso;
    return (uint32_t)(w->val[i] > iso) | (uint32_t)(w->val[i + S] > iso) << 1 |
           (uint32_t)(w->val[i + SS] > iso) << 2 | (uint32_t)(w->val[i + SS + S] > iso) << 3;
}

/* A column's four bits at corner positions 0, 2, 4, 6 (x = 0). */
static const uint8_t spread[16] = {0x00, 0x01, 0x04, 0x05, 0x10, 0x11, 0x14, 0x15,
                                   0x40, 0x41, 0x44, 0x45, 0x50, 0x51, 0x54, 0x55};

static int cell(iso_work *w, const uint32_t c[3], const iso_case *cs)
{
    uint32_t cref[ISO_MAX_CENTRES];
    int rc = 0;
    for (uint32_t k = 0; k < cs->ncentre && !rc; k++) rc = centre(w, c, cs, k, &cref[k]);
    if (rc || (rc = vec_grow(&w->tri, cs->ntri))) return rc;
    for (uint32_t t = 0; t < cs->ntri; t++) {
        uint32_t *r = (uint32_t *)w->tri.p + 3 * (w->tri.n + t);
        for (int i = 0; i < 3 && !rc; i++) {
            uint32_t s = cs->tri[t][i];
            if (s >= ISO_CENTRE_SLOT) r[i] = cref[s - ISO_CENTRE_SLOT];
            else rc = edge_ref(w, c, s, &r[i]);
        }
    }
    w->tri.n += cs->ntri;
    return rc;
}

/* Pass 2: the triangles of every cell. */
static int cells(iso_work *w, const uint32_t nc[3])
{
    const iso_case *tab = iso_cases();
    uint32_t S = w->S;
    for (uint32_t z = 0; z < nc[2]; z++)
        for (uint32_t y = 0; y < nc[1]; y++) {
            size_t r = (size_t)z * S + y;
            if (!rows_differ(w, r, r + 1) && !rows_differ(w, r, r + S) &&
                !rows_differ(w, r, r + S + 1))
                continue; /* four rows all inside or all outside */
            uint32_t lo = spread[column(w, sidx(w, 0, y, z))];
            for (uint32_t x = 0; x < nc[0]; x++) {
                uint32_t hi = spread[column(w, sidx(w, x + 1, y, z))];
                uint32_t c[3] = {x, y, z}, cs = lo | hi << 1;
                lo = hi;
                if (cs == 0 || cs == 255) continue;
                int rc = cell(w, c, &tab[cs]);
                if (rc) return rc;
            }
        }
    return 0;
}

static int begin_task(iso_work *w, const iso_params *p, const iso_task *t, uint32_t nc[3])
{
    uint32_t g[3];
    if (t->level >= p->height) return -EINVAL;
    iso_task_grid(p, t->level, g);
    w->p = p;
    w->level = t->level;
    for (int a = 0; a < 3; a++) {
        if (t->b[a] >= g[a]) return -EINVAL;
        w->b[a] = t->b[a];
        w->W[a] = p->dims[t->level][a] + 2;
        w->vs[a] = (double)p->scale[a] * (double)(1u << t->level);
        uint32_t left = p->dims[t->level][a] + 1 - t->b[a] * p->brick;
        nc[a] = left < p->brick ? left : p->brick;
    }
    w->keys.n = w->pos.n = w->nrm.n = w->cpos.n = w->cnrm.n = w->tri.n = w->ext.n = 0;
    return 0;
}

int iso_task_run(iso_work *w, const iso_params *p, const iso_input *in,
                 const iso_task *t, iso_piece *pc)
{
    uint32_t nc[3];
    int rc = begin_task(w, p, t, nc);
    if (rc) return rc;
    gather(w, in);
    if (classify_rows(w)) {
        rc = own_vertices(w, nc);
        if (!rc) rc = cells(w, nc);
        forget(w);
        if (rc) return rc;
    }
    *pc = (iso_piece){
        .key = iso_task_key(p, t),
        .nv = (uint32_t)w->keys.n, .nc = (uint32_t)w->cpos.n,
        .nt = (uint32_t)w->tri.n, .ne = (uint32_t)w->ext.n,
        .keys = w->keys.p, .pos = w->pos.p, .nrm = w->word ? w->nrm.p : NULL,
        .cpos = w->cpos.p, .cnrm = w->word ? w->cnrm.p : NULL,
        .tri = w->tri.p, .ext = w->ext.p,
    };
    return 0;
}
