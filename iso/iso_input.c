/* What a marching-cubes job reads: its parameters from the file and the
 * options, the raw bricks of the levels it uses (copied once into memory
 * every process reaches), and its tasks. */
#include <assert.h>
#include <errno.h>
#include <math.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "err.h"
#include "iso.h"
#include "par.h"
#include "prefault.h"

static int check_channel(const vod_info *in, err_info *e)
{
    if (in->voxel_bits == 16 || (in->flags & VOD_FLAG_FLOAT && in->channel != 4))
        return err_set(e, -EINVAL, "channel %u (%u-bit voxels) has no marching cubes "
                       "here: channels 1 to 4 do", in->channel, in->voxel_bits);
    if (in->height > ISO_MAX_LEVELS)
        return err_set(e, -EINVAL, "treeHeight %u: more levels than %u", in->height,
                       ISO_MAX_LEVELS);
    return 0;
}

static int set_levels(iso_params *p, const iso_request *rq, err_info *e)
{
    const double *radii = rq->radii;
    uint32_t nradii = rq->nradii;
    int level = rq->level;
    if (nradii > ISO_MAX_RADII)
        return err_set(e, -EINVAL, "at most %u LOD radii", ISO_MAX_RADII);
    for (uint32_t i = 0; i < nradii; i++) {
        if (!isfinite(radii[i]) || radii[i] < 0 || (i && !(radii[i] > radii[i - 1])))
            return err_set(e, -EINVAL, "LOD radii must be finite, >= 0 and increasing");
        p->radii[i] = radii[i];
    }
    if (level < 0 || (uint32_t)level >= p->height)
        return err_set(e, -EINVAL, "level %d: the file has levels 0..%u", level,
                       p->height - 1);
    p->level = (uint32_t)level;
    p->nradii = nradii;
    p->lod_top = nradii < p->height - 1 ? nradii : p->height - 1;
    p->block = p->brick > 1u << p->lod_top ? p->brick : 1u << p->lod_top;
    for (int a = 0; a < 3 && rq->center; a++) p->center[a] = rq->center[a];
    return 0;
}

int iso_params_make(const vod_file *f, const iso_request *rq, iso_params *p, err_info *e)
{
    const vod_info *in = vod_get_info(f);
    memset(p, 0, sizeof *p);
    if (rq->iso > 254) return err_set(e, -EINVAL, "iso %u: not in 0..254", rq->iso);
    int rc = check_channel(in, e);
    if (rc) return rc;
    p->iso = rq->iso;
    p->bits = in->voxel_bits;
    p->distance = in->channel == 4;
    p->normals = in->voxel_bits == 32 && !p->distance;
    p->brick = in->brick;
    p->height = in->height;
    for (uint32_t l = 0; l < in->height; l++) vod_level_dims(f, (int)l, p->dims[l]);
    for (int a = 0; a < 3; a++) {
        p->origin[a] = in->origin[a];
        p->scale[a] = in->voxel_scale[a];
    }
    return set_levels(p, rq, e);
}

/* The distance from the spheres' centre to the block's world box. */
static double block_distance(const iso_params *p, const uint32_t b[3])
{
    double side = p->block, d2 = 0;
    for (int a = 0; a < 3; a++) {
        double lo = p->origin[a] + (double)b[a] * side * p->scale[a];
        double hi = lo + side * p->scale[a], c = p->center[a];
        double d = c < lo ? lo - c : c > hi ? c - hi : 0;
        d2 += d * d;
    }
    return sqrt(d2);
}

uint32_t iso_block_level(const iso_params *p, const uint32_t b[3])
{
    if (!p->nradii) return p->level;
    double d = block_distance(p, b);
    uint32_t l = 0;
    while (l < p->nradii && d > p->radii[l]) l++;
    return l < p->lod_top ? l : p->lod_top;
}

void iso_task_grid(const iso_params *p, uint32_t level, uint32_t n[3])
{
    for (int a = 0; a < 3; a++) n[a] = p->dims[level][a] / p->brick + 1;
}

/* ---- the input ---- */

typedef struct {
    uint64_t key;
    const uint8_t *raw;
    uint64_t off;
    uint8_t state;
} brick_ref;

typedef struct {
    const iso_params *p;
    uint32_t level;
    brick_ref *v;
    size_t n, cap;
    int rc;
} collect_ctx;

/* A level-l brick is used when one of the blocks it covers uses level l. */
static int brick_used(const iso_params *p, uint32_t level, const uint32_t b[3])
{
    if (!p->nradii) return level == p->level;
    uint64_t side = (uint64_t)p->brick << level;
    uint32_t lo[3], hi[3], k[3];
    for (int a = 0; a < 3; a++) {
        lo[a] = (uint32_t)(b[a] * side / p->block);
        hi[a] = (uint32_t)(((b[a] + 1) * side - 1) / p->block);
    }
    for (k[2] = lo[2]; k[2] <= hi[2]; k[2]++)
        for (k[1] = lo[1]; k[1] <= hi[1]; k[1]++)
            for (k[0] = lo[0]; k[0] <= hi[0]; k[0]++)
                if (iso_block_level(p, k) == level) return 1;
    return 0;
}

static int collect_one(void *ud, const uint32_t b[3], const uint8_t *raw)
{
    collect_ctx *c = ud;
    if (!brick_used(c->p, c->level, b)) return 0;
    if (c->n == c->cap) {
        size_t cap = c->cap ? 2 * c->cap : 1024;
        brick_ref *v = realloc(c->v, cap * sizeof *v);
        if (!v) return c->rc = -ENOMEM;
        c->v = v;
        c->cap = cap;
    }
    uint64_t side = 1ull << (c->p->height - 1 - c->level);
    uint64_t lin = ((uint64_t)b[2] * side + b[1]) * side + b[0];
    c->v[c->n++] = (brick_ref){iso_brick_key(c->level, lin), raw, 0, ISO_BRICK_MIXED};
    return 0;
}

static int by_raw(const void *a, const void *b)
{
    const uint8_t *x = ((const brick_ref *)a)->raw, *y = ((const brick_ref *)b)->raw;
    return (x > y) - (x < y);
}

static int by_key(const void *a, const void *b)
{
    uint64_t x = ((const brick_ref *)a)->key, y = ((const brick_ref *)b)->key;
    return (x > y) - (x < y);
}

/* Every voxel of a raw brick inside (above iso), every one outside, or both. */
static uint8_t brick_state(const iso_params *p, const uint8_t *raw)
{
    size_t n = (size_t)p->brick * p->brick * p->brick;
    int in = 0, out = 0;
    for (size_t i = 0; i < n && !(in && out); i++) {
        uint32_t v = p->bits == 8      ? raw[i]
                     : p->bits == 1    ? (raw[i >> 3] >> (i & 7) & 1u) * 255u
                     : p->distance ? (raw[4 * i + 3] >> 7) * 255u /* the f32's sign */
                                       : vod_get32(raw + 4 * i) & 0xffu;
        if (v > p->iso) in = 1;
        else out = 1;
    }
    return in && out ? ISO_BRICK_MIXED : in ? ISO_BRICK_IN : ISO_BRICK_OUT;
}

static int levels_used(const iso_params *p, uint32_t *lo, uint32_t *hi)
{
    *lo = p->nradii ? 0 : p->level;
    *hi = p->nradii ? p->lod_top : p->level;
    return 0;
}

/* The unique bricks' copies and states, in pieces that the threads claim
 * in turn: a piece is an equal share of the unique bricks (the runs of c->v
 * with one raw brick, whose offsets are those of their unique copies), not
 * of c->v: the bricks the file shares (uniform ones) gather in a few runs,
 * and an even split of c->v left one part most of the copying.  Pieces,
 * several a thread, not one part each: the copy is the first touch of the
 * segment's pages, whose cost varies, and a thread left with the last
 * half alone ran 2-6 ms by itself (vox mesh of Scene 1 at 512^3). */
typedef struct {
    const iso_params *p;
    brick_ref *v;
    size_t n, raw_bytes, uniq, pieces;
    uint8_t *raw;
    /* The next piece to claim.  Relaxed: a claim orders nothing; what the
     * threads wrote is read after par_run joins them. */
    atomic_size_t next;
} copy_ctx;

/* The first of c->v whose copy is at or past unique brick u. */
static size_t first_from(const copy_ctx *c, size_t u)
{
    size_t lo = 0, hi = c->n, at = u * c->raw_bytes;
    while (lo < hi) {
        size_t mid = lo + (hi - lo) / 2;
        if (c->v[mid].off < at) lo = mid + 1;
        else hi = mid;
    }
    return lo;
}

static void copy_piece(copy_ctx *c, size_t k)
{
    size_t lo = first_from(c, c->uniq * k / c->pieces);
    size_t hi = first_from(c, c->uniq * (k + 1) / c->pieces);
    /* the pages faulted in by one call, not one fault each */
    if (lo < hi) prefault_write(c->raw + c->v[lo].off, c->v[hi - 1].off + c->raw_bytes - c->v[lo].off);
    for (size_t i = lo; i < hi; i++)
        if (i == 0 || c->v[i].raw != c->v[i - 1].raw) {
            memcpy(c->raw + c->v[i].off, c->v[i].raw, c->raw_bytes);
            c->v[i].state = brick_state(c->p, c->v[i].raw);
        }
}

static void copy_part(void *ud, unsigned k, unsigned parts)
{
    (void)k, (void)parts; /* the threads share one counter of pieces */
    copy_ctx *c = ud;
    for (size_t i; (i = atomic_fetch_add_explicit(&c->next, 1, memory_order_relaxed)) < c->pieces;)
        copy_piece(c, i);
}

int iso_input_make(const vod_file *f, const iso_params *p,
                   void *(*alloc)(void *ud, size_t bytes), void *ud, iso_input *in)
{
    return iso_input_make_threads(f, p, alloc, ud, 1, in);
}

int iso_input_make_threads(const vod_file *f, const iso_params *p,
                           void *(*alloc)(void *ud, size_t bytes), void *ud,
                           unsigned threads, iso_input *in)
{
    collect_ctx c = {.p = p};
    uint32_t lo, hi;
    levels_used(p, &lo, &hi);
    for (uint32_t l = lo; l <= hi && !c.rc; l++) {
        c.level = l;
        vod_foreach_brick(f, (int)l, collect_one, &c);
    }
    if (c.rc) {
        free(c.v);
        return c.rc;
    }
    /* bricks the file shares (the same pointer) are copied once */
    size_t raw_bytes = (size_t)p->brick * p->brick * p->brick * p->bits / 8, uniq = 0;
    if (c.n) qsort(c.v, c.n, sizeof *c.v, by_raw);
    for (size_t i = 0; i < c.n; i++) {
        if (i == 0 || c.v[i].raw != c.v[i - 1].raw) uniq++;
        c.v[i].off = (uniq - 1) * raw_bytes;
    }
    size_t st_bytes = (c.n + 7) / 8 * 8, bytes = c.n * 16 + st_bytes + uniq * raw_bytes;
    uint8_t *mem = alloc(ud, bytes ? bytes : 16);
    if (!mem) {
        free(c.v);
        return -ENOMEM;
    }
    uint64_t *keys = (uint64_t *)mem, *offs = keys + c.n;
    uint8_t *state = mem + c.n * 16, *raw = state + st_bytes;
    /* the copy is the first touch of raw's pages: on every thread, with
     * the states (a piece copies 1 MiB at least, eight pieces a thread) */
    size_t most = uniq * raw_bytes / (1u << 20) + 1;
    copy_ctx cc = {.p = p, .v = c.v, .n = c.n, .raw_bytes = raw_bytes, .uniq = uniq,
                   .pieces = 8 * (size_t)threads < most ? 8 * (size_t)threads : most, .raw = raw};
    atomic_init(&cc.next, 0);
    par_run(threads < cc.pieces ? threads : (unsigned)cc.pieces, copy_part, &cc);
    for (size_t i = 1; i < c.n; i++) /* a shared brick: its first's state */
        if (c.v[i].raw == c.v[i - 1].raw) c.v[i].state = c.v[i - 1].state;
    if (c.n) qsort(c.v, c.n, sizeof *c.v, by_key);
    for (size_t i = 0; i < c.n; i++) {
        keys[i] = c.v[i].key;
        offs[i] = c.v[i].off;
        state[i] = c.v[i].state;
    }
    *in = (iso_input){c.n, keys, offs, raw, uniq * raw_bytes, state};
    free(c.v);
    return 0;
}

/* ---- tasks ---- */

/* keys[0 .. n) in increasing order, a byte at a time from the lowest
 * (LSD radix; tmp holds n), the bytes all keys share skipped: the task
 * keys of a large file are hundreds of thousands, and qsort's calls were
 * the largest serial piece of vox mesh's set-up (3 ms of Scene 1's 25,000
 * keys at 512^3). */
static void sort_u64(uint64_t *keys, uint64_t *tmp, size_t n)
{
    if (n < 2) return;
    size_t count[256];
    for (unsigned shift = 0; shift < 64; shift += 8) {
        memset(count, 0, sizeof count);
        for (size_t i = 0; i < n; i++) count[keys[i] >> shift & 0xff]++;
        if (count[keys[0] >> shift & 0xff] == n) continue; /* one value: in order */
        for (size_t d = 0, at = 0; d < 256; d++) {
            size_t c = count[d];
            count[d] = at;
            at += c;
        }
        for (size_t i = 0; i < n; i++) tmp[count[keys[i] >> shift & 0xff]++] = keys[i];
        memcpy(keys, tmp, n * sizeof *keys);
    }
}

/* The task bricks that read file brick `key`: it and the next on each
 * axis (grid: iso_task_grid of each level). */
static size_t tasks_of(const iso_params *p, uint32_t grid[][3], uint64_t key, uint64_t *out)
{
    uint32_t l = (uint32_t)(key >> 58), b[3], s = p->height - 1 - l;
    uint64_t side = 1ull << s, lin = key & ((1ull << 58) - 1);
    const uint32_t *n = grid[l];
    b[0] = (uint32_t)(lin & (side - 1));
    b[1] = (uint32_t)(lin >> s & (side - 1));
    b[2] = (uint32_t)(lin >> s >> s);
    size_t k = 0;
    for (uint32_t c = 0; c < 8; c++) {
        uint32_t t[3];
        int ok = 1;
        for (int a = 0; a < 3; a++) {
            t[a] = b[a] + (c >> a & 1u);
            ok &= t[a] < n[a];
        }
        if (ok) out[k++] = iso_brick_key(l, ((uint64_t)t[2] * n[1] + t[1]) * n[0] + t[0]);
    }
    return k;
}

/* A file brick's state; a brick the input does not have is empty: outside. */
static uint8_t state_of(const iso_input *in, uint64_t key)
{
    uint64_t lo = 0, hi = in->n;
    while (lo < hi) {
        uint64_t mid = lo + (hi - lo) / 2;
        if (in->keys[mid] < key) lo = mid + 1;
        else hi = mid;
    }
    return lo < in->n && in->keys[lo] == key ? in->state[lo] : ISO_BRICK_OUT;
}

/* Can task t's samples (voxels b B - 1 .. b B + B - 1 of its level on each
 * axis, from file bricks b - 1 and b) hold both an inside and an outside
 * one?  All from bricks wholly outside: no.  All from bricks wholly inside,
 * none past the volume (read as 0) and one level (adaptive levels read the
 * other levels' blocks as 0): no. */
static int task_needed(const iso_params *p, const iso_input *in, const iso_task *t)
{
    if (!in->state) return 1;
    uint32_t l = t->level, B = p->brick;
    uint64_t side = 1ull << (p->height - 1 - l);
    int all_in = !p->nradii, all_out = 1;
    for (int a = 0; a < 3; a++)
        all_in &= t->b[a] > 0 && (uint64_t)t->b[a] * B + B <= p->dims[l][a];
    for (uint32_t c = 0; c < 8 && (all_in || all_out); c++) {
        int64_t f[3];
        int inside = 1;
        for (int a = 0; a < 3; a++) {
            f[a] = (int64_t)t->b[a] - (c >> a & 1u ? 0 : 1);
            inside &= f[a] >= 0 && (uint64_t)f[a] < side;
        }
        uint8_t s = inside ? state_of(in, iso_brick_key(l, ((uint64_t)f[2] * side + (uint64_t)f[1]) *
                                                               side + (uint64_t)f[0]))
                           : ISO_BRICK_OUT;
        all_in &= s == ISO_BRICK_IN;
        all_out &= s == ISO_BRICK_OUT;
    }
    return !all_in && !all_out;
}

int iso_tasks(const iso_params *p, const iso_input *in, iso_task **out, uint64_t *n)
{
    /* up to 8 task keys a file brick, then as many for the sort's copy */
    size_t most = (in->n ? in->n : 1) * 8;
    uint64_t *keys = malloc(2 * most * sizeof *keys);
    if (!keys) return -ENOMEM;
    uint32_t grid[ISO_MAX_LEVELS][3];
    assert(p->height <= ISO_MAX_LEVELS); /* iso_params_make refuses more */
    for (uint32_t l = 0; l < p->height; l++) iso_task_grid(p, l, grid[l]);
    size_t k = 0;
    for (uint64_t i = 0; i < in->n; i++) k += tasks_of(p, grid, in->keys[i], keys + k);
    sort_u64(keys, keys + most, k);
    size_t u = 0;
    for (size_t i = 0; i < k; i++)
        if (!u || keys[i] != keys[u - 1]) keys[u++] = keys[i];
    iso_task *t = malloc((u ? u : 1) * sizeof *t);
    if (!t) {
        free(keys);
        return -ENOMEM;
    }
    size_t m = 0;
    for (size_t i = 0; i < u; i++) {
        uint32_t l = (uint32_t)(keys[i] >> 58), g[3];
        uint64_t lin = keys[i] & ((1ull << 58) - 1);
        iso_task_grid(p, l, g);
        t[m] = (iso_task){l, {(uint32_t)(lin % g[0]), (uint32_t)(lin / g[0] % g[1]),
                              (uint32_t)(lin / g[0] / g[1])}};
        m += task_needed(p, in, &t[m]);
    }
    free(keys);
    *out = t;
    *n = m;
    return 0;
}
