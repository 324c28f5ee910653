/* The brick-sparse volume's mip levels and its VOD brick source
 * (vod_volume.h; the layout and the store are in vod_volume.c, the
 * entries' meaning at the top of that file). */
#include "vod_volume_int.h"

#include <assert.h>
#include <errno.h>
#include <stdatomic.h>
#include <stdbool.h>
#include <stdlib.h>
#include <string.h>
#ifdef __SSE2__
#include <emmintrin.h>
#endif

#include "par.h"
#include "vod_downsample.h"
#include "voxel.h"

/* ---- mip levels ---- */

static uint64_t load64(const uint8_t *p)
{
    uint64_t w; /* byte k in bits 8k .. 8k + 7 */
    memcpy(&w, p, 8);
#if __BYTE_ORDER__ == __ORDER_BIG_ENDIAN__
    w = __builtin_bswap64(w);
#endif
    return w;
}

static uint32_t channels_of(const vod_volume *v)
{
    if (v->f32) return 1u << VOXEL_CH_DISTANCE;
    return 1u << VOXEL_CH_OCCUPANCY |
           1u << (v->bits == 8 ? VOXEL_CH_DENSITY : VOXEL_CH_SURFACE);
}

typedef struct {
    vod_volume *v;
    int l, ch;          /* building level l from level l-1 */
    uint32_t *out;      /* S^3 parent voxels */
    uint8_t *out8;      /* the same memory, as bytes: 8-bit volumes' */
    uint32_t *child;    /* S^3: a packed child's voxels (then out is too) */
    bool nonempty;      /* the parent's footprint holds a voxel */
} mip_ctx;

/* The octant of the parent from child brick d, any voxel width and
 * channel; returns the OR of the child's voxels. */
static uint32_t mip_octant_any(mip_ctx *m, const uint8_t *d, uint32_t ox,
                               uint32_t oy, uint32_t oz)
{
    const vod_volume *v = m->v;
    uint32_t half = v->sbrick / 2, c[8], any = 0;
    for (uint32_t z = 0; z < half; z++)
        for (uint32_t y = 0; y < half; y++)
            for (uint32_t x = 0; x < half; x++) {
                for (unsigned i = 0; i < 8; i++) {
                    c[i] = vox_get(v, d, vox_index(v, 2 * x + (i & 1u),
                                                   2 * y + (i >> 1 & 1u),
                                                   2 * z + (i >> 2 & 1u)));
                    any |= c[i];
                }
                m->out[vox_index(v, ox + x, oy + y, oz + z)] = vod_downsample(m->ch, c);
            }
    return any;
}

/* Channel 1 of 4 parent voxels from the 8 x-children of 4 rows (a..d, 8
 * bytes each): out[k] = 1 when a byte 2k or 2k+1 of any row is non-zero.
 * Returns the OR of the children. */
static uint64_t or_pairs4(const uint8_t *a, const uint8_t *b, const uint8_t *c,
                          const uint8_t *d, uint8_t *out)
{
    uint64_t w = load64(a) | load64(b) | load64(c) | load64(d);
    uint64_t p = w | w >> 8; /* byte 2k: the OR of children 2k and 2k + 1 */
    const uint64_t low7 = 0x7f7f7f7f7f7f7f7full;
    uint64_t t = ((((p & low7) + low7) | p) & 0x0080008000800080ull) >> 7;
    uint32_t q = (uint32_t)((t & 1u) | (t >> 8 & 0x100u) | (t >> 16 & 0x10000u) |
                            (t >> 24 & 0x1000000u));
    for (int k = 0; k < 4; k++) out[k] = (uint8_t)(q >> (8 * k));
    return w;
}

#ifdef __SSE2__
/* or_pairs4 for 8 parent voxels (16 bytes of each row), with SSE2;
 * returns whether any child is non-zero. */
static bool or_pairs8(const uint8_t *a, const uint8_t *b, const uint8_t *c,
                      const uint8_t *d, uint8_t *out)
{
    __m128i w = _mm_or_si128(
        _mm_or_si128(_mm_loadu_si128((const __m128i *)a), _mm_loadu_si128((const __m128i *)b)),
        _mm_or_si128(_mm_loadu_si128((const __m128i *)c), _mm_loadu_si128((const __m128i *)d)));
    /* each 16-bit lane: a pair of children, 0 or not */
    __m128i zero = _mm_setzero_si128(), empty = _mm_cmpeq_epi16(w, zero);
    __m128i one = _mm_andnot_si128(empty, _mm_set1_epi16(1));
    _mm_storel_epi64((__m128i *)out, _mm_packus_epi16(one, one));
    return _mm_movemask_epi8(empty) != 0xffff;
}
#endif

/* The same for 8-bit voxels and channels 1 and 2 (vod_downsample's rules
 * written out: any child non-zero, or the mean rounded half up), the mesh
 * and CSG volumes' common case, into the parent's bytes m->out8. */
static uint32_t mip_octant8(mip_ctx *m, const uint8_t *d, uint32_t ox,
                            uint32_t oy, uint32_t oz)
{
    const vod_volume *v = m->v;
    size_t S = v->sbrick, half = S / 2, SS = S * S;
    uint64_t any = 0;
    for (size_t z = 0; z < half; z++)
        for (size_t y = 0; y < half; y++) {
            const uint8_t *r0 = d + (2 * z * S + 2 * y) * S, *r1 = r0 + S;
            const uint8_t *r2 = r0 + SS, *r3 = r1 + SS;
            uint8_t *out = m->out8 + ((oz + z) * S + oy + y) * S + ox;
            size_t x = 0;
#ifdef __SSE2__
            if (m->ch == VOXEL_CH_OCCUPANCY)
                for (; x + 8 <= half; x += 8)
                    any |= or_pairs8(r0 + 2 * x, r1 + 2 * x, r2 + 2 * x, r3 + 2 * x, out + x);
#endif
            if (m->ch == VOXEL_CH_OCCUPANCY)
                for (; x + 4 <= half; x += 4) /* 8 children a word */
                    any |= or_pairs4(r0 + 2 * x, r1 + 2 * x, r2 + 2 * x, r3 + 2 * x,
                                     out + x);
            for (; x < half; x++) {
                size_t i = 2 * x;
                uint32_t ors = r0[i] | r0[i + 1] | r1[i] | r1[i + 1] | r2[i] |
                              r2[i + 1] | r3[i] | r3[i + 1];
                any |= ors;
                out[x] = (uint8_t)(m->ch == VOXEL_CH_DENSITY
                                       ? (r0[i] + r0[i + 1] + r1[i] + r1[i + 1] + r2[i] +
                                          r2[i + 1] + r3[i] + r3[i + 1] + 4u) / 8u
                                       : ors != 0);
            }
        }
    return any != 0;
}

/* The octant of the parent that child entry e (level l-1) covers, from
 * (ox, oy, oz) in the parent. */
static void mip_octant(mip_ctx *m, uint32_t e, uint32_t ox, uint32_t oy,
                       uint32_t oz)
{
    const vod_volume *v = m->v;
    uint32_t S = v->sbrick, half = S / 2, c[8];
    if (!is_alloc(e)) {
        for (int i = 0; i < 8; i++) c[i] = uval(v, e);
        uint32_t d = vod_downsample(m->ch, c);
        m->nonempty = m->nonempty || e != 0;
        for (uint32_t z = 0; z < half; z++)
            for (uint32_t y = 0; y < half; y++) {
                size_t at = vox_index(v, ox, oy + y, oz + z);
                if (v->bits == 8) memset(m->out8 + at, (int)d, half);
                else
                    for (uint32_t x = 0; x < half; x++) m->out[at + x] = d;
            }
        return;
    }
    const uint8_t *d = brick_data(v, e);
    if (v->packed) {
        vod_pack_range(v, d, 0, (size_t)S * S * S, m->child);
        d = (const uint8_t *)m->child;
    }
    /* 8-bit voxels give channels 1 and 2 only (channels_of) */
    uint32_t any = v->bits == 8 ? mip_octant8(m, d, ox, oy, oz)
                                : mip_octant_any(m, d, ox, oy, oz);
    /* a mip child with memory has a non-empty footprint by construction;
     * a level-0 one only if some voxel is non-zero */
    m->nonempty = m->nonempty || m->l > 1 || any;
}

/* The parent of 8 children that are all the same entry without memory
 * (all empty, or all uniform with one value), without visiting a voxel:
 * what the general path below gives for them.  false when they differ or
 * the parent's value cannot be a uniform entry. */
static bool mip_same_children(mip_ctx *m, const uint32_t p[3], uint32_t *entry)
{
    uint32_t e0 = 0;
    for (unsigned i = 0; i < 8; i++) {
        uint32_t c[3] = {2 * p[0] + (i & 1u), 2 * p[1] + (i >> 1 & 1u),
                         2 * p[2] + (i >> 2 & 1u)};
        uint32_t e = entry_at(m->v, m->l - 1, c);
        if (is_alloc(e) || (i && e != e0)) return false;
        e0 = e;
    }
    if (e0 == 0) {
        *entry = 0;
        return true;
    }
    uint32_t c[8];
    for (int i = 0; i < 8; i++) c[i] = uval(m->v, e0);
    /* a mip entry is 0 only for an empty footprint: a value 0 is uniform */
    uint32_t d = vod_downsample(m->ch, c), u = d ? vod_vol_uentry(m->v, d) : ENTRY_UNIFORM;
    if (!u) return false;
    *entry = u;
    return true;
}

/* Brick p of level m->l from its 8 children, into *entry (whose memory
 * is used again when it has some: a column built a second time). */
static int mip_brick(mip_ctx *m, const uint32_t p[3], uint32_t *entry)
{
    vod_volume *v = m->v;
    uint32_t half = v->sbrick / 2, old = *entry;
    if (mip_same_children(m, p, entry)) return 0;
    m->nonempty = false;
    for (unsigned i = 0; i < 8; i++) {
        uint32_t c[3] = {2 * p[0] + (i & 1u), 2 * p[1] + (i >> 1 & 1u),
                         2 * p[2] + (i >> 2 & 1u)};
        mip_octant(m, entry_at(v, m->l - 1, c), (i & 1u) * half,
                   (i >> 1 & 1u) * half, (i >> 2 & 1u) * half);
    }
    *entry = 0;
    if (!m->nonempty) return 0;
    uint64_t n = (uint64_t)v->sbrick * v->sbrick * v->sbrick, i;
    int64_t u = vod_vol_uniform_value(v, v->bits == 8 ? m->out8 : (const uint8_t *)m->out);
    uint32_t ue = u > 0 ? vod_vol_uentry(v, (uint32_t)u) : u == 0 ? ENTRY_UNIFORM : 0;
    if (ue) {
        *entry = ue;
        return 0;
    }
    if (v->packed) {
        uint32_t pe = vod_pack_store(v, old, m->out, false);
        *entry = pe;
        return pe ? 0 : -ENOMEM;
    }
    uint32_t e = is_alloc(old) ? old : vod_vol_pool_take(v, 0, false); /* written whole below */
    if (!e) return -ENOMEM;
    uint8_t *d = brick_data(v, e);
    if (v->bits == 8) memcpy(d, m->out8, n); /* the bytes are the voxels */
    else
        for (i = 0; i < n; i++) vox_put(v, d, (size_t)i, m->out[i]);
    *entry = e;
    return 0;
}

static int build_level(mip_ctx *m)
{
    vod_volume *v = m->v;
    const uint32_t *g = v->grid[m->l];
    uint32_t *t = table(v, m->l), p[3];
    uint64_t k = 0;
    for (p[2] = 0; p[2] < g[2]; p[2]++)
        for (p[1] = 0; p[1] < g[1]; p[1]++)
            for (p[0] = 0; p[0] < g[0]; p[0]++, k++) {
                int rc = mip_brick(m, p, &t[k]);
                if (rc) return rc;
            }
    return 0;
}

/* Levels first..levels of the level-`levels` brick columns [lo, hi),
 * every z. */
static int build_columns(mip_ctx *m, int first, int levels, const uint32_t lo[2],
                         const uint32_t hi[2])
{
    vod_volume *v = m->v;
    int rc = 0;
    for (m->l = first; m->l <= levels && !rc; m->l++) {
        const uint32_t *g = v->grid[m->l];
        uint32_t *t = table(v, m->l), p[3], k = (uint32_t)(levels - m->l);
        uint32_t x1 = hi[0] << k < g[0] ? hi[0] << k : g[0];
        uint32_t y1 = hi[1] << k < g[1] ? hi[1] << k : g[1];
        for (p[2] = 0; p[2] < g[2] && !rc; p[2]++)
            for (p[1] = lo[1] << k; p[1] < y1 && !rc; p[1]++)
                for (p[0] = lo[0] << k; p[0] < x1 && !rc; p[0]++)
                    rc = mip_brick(m, p, &t[((uint64_t)p[2] * g[1] + p[1]) * g[0] + p[0]]);
    }
    return rc;
}

/* The scratch of a mip build: a parent brick, and a packed child's voxels. */
static int mip_ctx_init(mip_ctx *m, vod_volume *v, int channel)
{
    size_t n = (size_t)v->sbrick * v->sbrick * v->sbrick;
    *m = (mip_ctx){.v = v, .ch = channel, .out = malloc(n * sizeof *m->out)};
    m->out8 = (uint8_t *)m->out;
    if (v->packed) m->child = malloc(n * sizeof *m->child);
    return m->out && (m->child || !v->packed) ? 0 : -ENOMEM;
}

static void mip_ctx_free(mip_ctx *m)
{
    free(m->out);
    free(m->child);
}

static bool mip_args_ok(const vod_volume *v, int channel, int levels)
{
    return channel >= 0 && channel <= 31 && (channels_of(v) >> channel & 1u) &&
           levels >= 1 && levels <= v->depth;
}

int vod_volume_mip_columns(vod_volume *v, int channel, int levels,
                           const uint32_t lo[2], const uint32_t hi[2])
{
    if (!mip_args_ok(v, channel, levels)) return -EINVAL;
    for (int a = 0; a < 2; a++) /* hi is clipped to the grid */
        if (lo[a] >= hi[a] || lo[a] >= v->grid[levels][a]) return -EINVAL;
    assert(v->mip_channel == 0 && v->low_levels == 0 &&
           "mip_columns runs before prepare() and vod_volume_mips_low()");
    mip_ctx m;
    if (mip_ctx_init(&m, v, channel)) return -ENOMEM;
    int rc = build_columns(&m, 1, levels, lo, hi);
    mip_ctx_free(&m);
    return rc;
}

int vod_volume_mips_low(vod_volume *v, int channel, int levels)
{
    if (!mip_args_ok(v, channel, levels) || v->mip_channel) return -EINVAL;
    v->low_channel = channel;
    v->low_levels = levels;
    return 0;
}

/* The levels prepare() builds by columns, on every CPU: its columns of
 * level `top` handed out one at a time (relaxed: a counter of disjoint
 * columns, read after par_run's join like rc). */
typedef struct {
    vod_volume *v;
    int channel, first, top;
    atomic_uint next;
    atomic_int rc;
} prep_par;

static void prep_part(void *ud, unsigned k, unsigned n)
{
    prep_par *p = ud;
    const uint32_t *g = p->v->grid[p->top];
    mip_ctx m;
    (void)k, (void)n;
    int rc = mip_ctx_init(&m, p->v, p->channel);
    for (unsigned c; !rc && (c = atomic_fetch_add_explicit(&p->next, 1, memory_order_relaxed)) <
                            g[0] * g[1];) {
        uint32_t lo[2] = {c % g[0], c / g[0]}, hi[2] = {lo[0] + 1, lo[1] + 1};
        rc = build_columns(&m, p->first, p->top, lo, hi);
    }
    mip_ctx_free(&m);
    if (rc) atomic_store_explicit(&p->rc, rc, memory_order_relaxed);
}

/* Levels first.. of the channel: those whose columns give each of the
 * process's CPUs PREP_COLUMNS or more by columns on all of them at once
 * (issue 24: the mesh job's levels above its tiles were 11-13 ms of one
 * thread, every worker waiting), the few above one by one.  Every brick
 * is built from its children alone, so the order changes no voxel. */
#define PREP_COLUMNS 4

static int build_levels(vod_volume *v, int channel, int first)
{
    unsigned cpus = par_cpus();
    int top = first - 1;
    /* a distance volume's wide uniform values are found or added by one
     * writer at a time (vod_vol_uentry): its levels stay on one thread */
    while (cpus > 1 && !v->f32 && top < v->depth &&
           (uint64_t)v->grid[top + 1][0] * v->grid[top + 1][1] >= PREP_COLUMNS * cpus)
        top++;
    for (int l = first; l <= v->depth; l++)
        memset(table(v, l), 0, 4 * grid_bricks(v, l));
    prep_par p = {.v = v, .channel = channel, .first = first, .top = top};
    atomic_init(&p.next, 0);
    atomic_init(&p.rc, 0);
    if (top >= first) par_run(cpus, prep_part, &p);
    int rc = atomic_load_explicit(&p.rc, memory_order_relaxed);
    if (rc) return rc;
    mip_ctx m;
    rc = mip_ctx_init(&m, v, channel);
    for (m.l = top + 1; m.l <= v->depth && !rc; m.l++) /* top >= first - 1 */
        rc = build_level(&m);
    mip_ctx_free(&m);
    return rc;
}

static int vol_prepare(vod_source *s, const vod_layout *L, int channel)
{
    (void)L; /* every level is built: the writer needs at most depth */
    vod_volume *v = s->ctx;
    if (channel < 0 || channel > 31 || !(channels_of(v) >> channel & 1u))
        return -EINVAL;
    if (v->mip_channel == channel) return 0;
    vod_vol_drop_mips(v);
    /* the levels built by column, when they are this channel's */
    int first = v->low_levels && v->low_channel == channel ? v->low_levels + 1 : 1;
    if (first == 1) v->low_levels = 0; /* another channel's: built over */
    v->mip_base = atomic_load_explicit(&v->pool_used, memory_order_relaxed);
    int rc = build_levels(v, channel, first);
    v->mip_channel = channel;
    if (rc) vod_vol_drop_mips(v); /* the levels built so far go back too */
    return rc;
}

/* ---- the source ---- */

static int channel_of_bits(const vod_volume *v, uint32_t bits)
{
    if (v->f32 && bits == 32) return VOXEL_CH_DISTANCE;
    return bits == 1 ? VOXEL_CH_OCCUPANCY : bits == 8 ? VOXEL_CH_DENSITY
                                                      : VOXEL_CH_SURFACE;
}

/* Some voxel of level-0 brick e in the box [lo, lo + side) is non-zero. */
static bool any_nonzero(const vod_volume *v, uint32_t e, const uint32_t lo[3],
                        uint32_t side)
{
    if (!is_alloc(e)) return e != 0;
    if (side == v->sbrick &&
        !atomic_load_explicit(&v->zero_bricks, memory_order_relaxed))
        return true; /* no zero was ever written into a brick's memory */
    const uint8_t *d = brick_data(v, e);
    if (v->packed && side == v->sbrick) return vod_pack_any(v, d);
    for (uint32_t z = lo[2]; z < lo[2] + side; z++)
        for (uint32_t y = lo[1]; y < lo[1] + side; y++)
            for (uint32_t x = lo[0]; x < lo[0] + side; x++)
                if (brick_voxel(v, e, vox_index(v, x, y, z))) return true;
    return false;
}

/* Node n's full-resolution cube (2^k voxels per axis) holds a voxel.  A
 * cube of at least a storage brick is one brick of the level m where
 * bricks are that size; a smaller one lies in one level-0 brick. */
static bool footprint_nonempty(const vod_volume *v, const vod_layout *L,
                               const vod_node *n)
{
    uint32_t b[3] = {n->bx, n->by, n->bz}, zero[3] = {0, 0, 0};
    int k = (int)(L->brick_log2 + n->level), m = k - (int)v->slog2;
    if (m >= 0) {
        if (m > v->depth) { /* a brick larger than the whole volume */
            if (b[0] | b[1] | b[2]) return false;
            m = v->depth;
        }
        if (m >= 1 && !v->mip_channel) return true; /* not prepared: cannot tell */
        uint32_t e = entry_at(v, m, b);
        return m >= 1 ? e != 0 : any_nonzero(v, e, zero, v->sbrick);
    }
    uint32_t lo[3], sb[3], mask = v->sbrick - 1;
    for (int a = 0; a < 3; a++) {
        lo[a] = (b[a] << k) & mask;
        sb[a] = (b[a] << k) >> v->slog2;
    }
    return any_nonzero(v, entry_at(v, 0, sb), lo, 1u << k);
}

/* Every storage brick under node n's level-l brick is uniform with one
 * value (a brick past the grid is 0); in the channel's terms. */
static bool brick_uniform(const vod_volume *v, const vod_layout *L,
                          const vod_node *n, uint32_t *value)
{
    int l = (int)n->level, ch = channel_of_bits(v, L->voxel_bits);
    if (l > v->depth || (l >= 1 && v->mip_channel != ch)) return false;
    uint32_t B = L->brick, per = B >= v->sbrick ? B >> v->slog2 : 1, b0[3], b[3];
    b0[0] = (n->bx * B) >> v->slog2;
    b0[1] = (n->by * B) >> v->slog2;
    b0[2] = (n->bz * B) >> v->slog2;
    bool first = true;
    for (uint32_t z = 0; z < per; z++)
        for (uint32_t y = 0; y < per; y++)
            for (uint32_t x = 0; x < per; x++) {
                b[0] = b0[0] + x, b[1] = b0[1] + y, b[2] = b0[2] + z;
                uint32_t e = entry_at(v, l, b);
                if (is_alloc(e)) return false;
                uint32_t u = uval(v, e);
                if (l == 0 && ch == VOXEL_CH_OCCUPANCY) u = u != 0;
                if (!first && u != *value) return false;
                *value = u;
                first = false;
            }
    return true;
}

static int vol_region(const vod_source *s, const vod_layout *L, vod_node *n)
{
    const vod_volume *v = s->ctx;
    n->value = 0;
    n->ref = 0;
    if (!footprint_nonempty(v, L, n)) return VOD_REGION_EMPTY;
    return brick_uniform(v, L, n, &n->value) ? VOD_REGION_UNIFORM : VOD_REGION_MIXED;
}

/* Voxel i of a raw brick (spec section 5) := val. */
static inline void raw_put(uint8_t *raw, uint32_t bits, size_t i, uint32_t val)
{
    if (bits == 32) vod_put32(raw + 4 * i, val);
    else if (bits == 8) raw[i] = (uint8_t)val;
    else if (val) raw[i >> 3] |= (uint8_t)(1u << (i & 7));
}

/* Bit k set where byte k of s[0, 8) is non-zero, without a branch or a
 * loop: each byte's high bit is set when it is non-zero (its low 7 bits
 * plus 0x7f carry into it, or it was set), then the multiplication gathers
 * the 8 high bits (moved to bit 0 of their bytes) into the top byte. */
static inline uint8_t nonzero_bits8(const uint8_t *s)
{
    uint64_t w = load64(s);
    const uint64_t low7 = 0x7f7f7f7f7f7f7f7full, high = 0x8080808080808080ull;
    uint64_t t = (((w & low7) + low7) | w) & high;
    return (uint8_t)(((t >> 7) * 0x0102040810204080ull) >> 56);
}

/* n voxels of a row of 8-bit voxels (src; NULL: all u) as bits of a
 * channel-1 raw brick from bit r on: whole bytes at a time where they are
 * aligned (a row of a 16^3 brick is two). */
static void copy_row_bits8(uint8_t *raw, size_t r, const uint8_t *src, uint32_t u,
                           uint32_t n)
{
    uint32_t x = 0;
    for (; x < n && ((r + x) & 7); x++)
        if (src ? src[x] : u) raw[(r + x) >> 3] |= (uint8_t)(1u << ((r + x) & 7));
    for (; x + 8 <= n; x += 8)
        raw[(r + x) >> 3] |= src ? nonzero_bits8(src + x) : u ? 0xff : 0;
    for (; x < n; x++)
        if (src ? src[x] : u) raw[(r + x) >> 3] |= (uint8_t)(1u << ((r + x) & 7));
}

/* The part of a storage brick that lies in a raw brick: the storage
 * brick's data d (NULL: all u) and low corner o, the raw brick's side B
 * and low corner lo, and the box [a0, a1) the two share. */
typedef struct {
    const uint8_t *d;
    uint32_t u, B;
    uint32_t o[3], lo[3], a0[3], a1[3];
} brick_part;

/* Part p (8-bit voxels; d NULL: all u, not 0) as channel-1 bits of its raw
 * brick, when every row starts and ends on a byte of it (the usual case:
 * bricks of 8 voxels or more): whole bytes, no bit offsets. */
static void copy_bytes_bits8(const vod_volume *v, const brick_part *p, uint8_t *raw)
{
    const uint8_t *d = p->d;
    const uint32_t B = p->B, *o = p->o, *lo = p->lo, *a0 = p->a0, *a1 = p->a1;
    uint32_t n8 = (a1[0] - a0[0]) / 8;
    size_t S = v->sbrick, row = B / 8; /* bytes from a row to the next, in raw */
    uint8_t *out0 = raw + (((size_t)(a0[2] - lo[2]) * B + (a0[1] - lo[1])) * B + (a0[0] - lo[0])) / 8;
    size_t s0 = vox_index(v, a0[0] - o[0], a0[1] - o[1], a0[2] - o[2]);
    /* rows and slices stepped, not recomputed: this is the writer's fill of
     * every mesh and CSG occupancy brick */
    for (uint32_t z = a0[2]; z < a1[2]; z++, out0 += row * B, s0 += S * S) {
        uint8_t *out = out0;
        size_t s = s0;
        for (uint32_t y = a0[1]; y < a1[1]; y++, out += row, s += S) {
            if (!d) {
                memset(out, 0xff, n8);
                continue;
            }
            const uint8_t *src = d + s;
            uint32_t k = 0;
#ifdef __SSE2__
            /* 16 voxels at once: a byte compare and its mask, bit i voxel i */
            for (; k + 2 <= n8; k += 2) {
                __m128i x = _mm_loadu_si128((const __m128i *)(src + 8 * k));
                unsigned m = ~(unsigned)_mm_movemask_epi8(_mm_cmpeq_epi8(x, _mm_setzero_si128()));
                out[k] |= (uint8_t)m;
                out[k + 1] |= (uint8_t)(m >> 8);
            }
#endif
            for (; k < n8; k++) out[k] |= nonzero_bits8(src + 8 * k);
        }
    }
}

/* n 32-bit voxels of a row (src, the volume's native u32s; NULL: all u)
 * into a raw brick's little-endian ones: the row at once where the two are
 * the same bytes (the distance's and the surface's every brick). */
static void copy_row32(uint8_t *raw, const uint8_t *src, uint32_t u, uint32_t n)
{
#if __BYTE_ORDER__ == __ORDER_LITTLE_ENDIAN__
    if (src) {
        memcpy(raw, src, (size_t)n * 4);
        return;
    }
#endif
    for (uint32_t x = 0; x < n; x++) {
        uint32_t w;
        if (src) memcpy(&w, src + 4 * x, 4);
        vod_put32(raw + 4 * x, src ? w : u);
    }
}

/* The part of storage brick (entry e, low corner o, level-l voxels) that
 * lies in the raw brick whose low corner is lo. */
static void copy_part(const vod_volume *v, const vod_layout *L, uint32_t e,
                      const uint32_t o[3], const uint32_t lo[3], uint8_t *raw)
{
    brick_part p = {.d = is_alloc(e) ? brick_data(v, e) : NULL, .u = uval(v, e),
                    .B = L->brick};
    uint32_t B = L->brick, S = v->sbrick, *a0 = p.a0, *a1 = p.a1;
    for (int a = 0; a < 3; a++) {
        p.o[a] = o[a];
        p.lo[a] = lo[a];
        a0[a] = o[a] > lo[a] ? o[a] : lo[a];
        a1[a] = o[a] + S < lo[a] + B ? o[a] + S : lo[a] + B;
    }
    const uint8_t *d = p.d;
    uint32_t u = p.u;
    if (L->voxel_bits == 1 && v->bits == 8 && B % 8 == 0 && (a0[0] - lo[0]) % 8 == 0 &&
        (a1[0] - a0[0]) % 8 == 0) {
        copy_bytes_bits8(v, &p, raw);
        return;
    }
    /* a packed brick's rows: a slice's at once when they are whole (one
     * vod_pack_range instead of one a row: the distance's every brick) */
    uint32_t rows[VOD_VOLUME_MAX_BRICK * VOD_VOLUME_MAX_BRICK];
    bool whole = d && v->packed && a1[0] - a0[0] == S;
    for (uint32_t z = a0[2]; z < a1[2]; z++) {
        if (whole)
            vod_pack_range(v, d, vox_index(v, 0, a0[1] - o[1], z - o[2]),
                           (size_t)(a1[1] - a0[1]) * S, rows);
        for (uint32_t y = a0[1]; y < a1[1]; y++) {
            size_t r = ((size_t)(z - lo[2]) * B + (y - lo[1])) * B + (a0[0] - lo[0]);
            size_t s = vox_index(v, a0[0] - o[0], y - o[1], z - o[2]);
            uint32_t n = a1[0] - a0[0];
            const uint8_t *src = d ? d + s * (v->bits / 8) : NULL; /* the row's voxels */
            if (whole) {
                src = (const uint8_t *)(rows + (size_t)(y - a0[1]) * S);
            } else if (d && v->packed) {
                vod_pack_range(v, d, s, n, rows);
                src = (const uint8_t *)rows;
            }
            if (L->voxel_bits == 1 && v->bits == 8)
                copy_row_bits8(raw, r, src, u, n);
            else if (L->voxel_bits == 8 && v->bits == 8) /* a row at a time */
                src ? memcpy(raw + r, src, n) : memset(raw + r, (int)u, n);
            else if (L->voxel_bits == 32 && v->bits == 32)
                copy_row32(raw + 4 * r, src, u, n);
            else
                for (uint32_t x = 0; x < n; x++)
                    raw_put(raw, L->voxel_bits, r + x, src ? vox_get(v, src, x) : u);
        }
    }
}

static int vol_fill(const vod_source *s, const vod_layout *L, const vod_node *n,
                    uint8_t *raw)
{
    const vod_volume *v = s->ctx;
    int l = (int)n->level, ch = channel_of_bits(v, L->voxel_bits);
    if (!(channels_of(v) >> ch & 1u) || l > v->depth ||
        (l >= 1 && v->mip_channel != ch))
        return -EINVAL;
    uint32_t B = L->brick, lo[3] = {n->bx * B, n->by * B, n->bz * B}, b[3], o[3];
    const uint32_t *g = v->grid[l];
    uint32_t b1[3];
    for (int a = 0; a < 3; a++) {
        uint32_t last = (lo[a] + B - 1) >> v->slog2;
        b1[a] = last < g[a] ? last + 1 : g[a];
    }
    for (b[2] = lo[2] >> v->slog2; b[2] < b1[2]; b[2]++)
        for (b[1] = lo[1] >> v->slog2; b[1] < b1[1]; b[1]++)
            for (b[0] = lo[0] >> v->slog2; b[0] < b1[0]; b[0]++) {
                uint32_t e = entry_at(v, l, b);
                if (e == 0 || e == ENTRY_UNIFORM) continue; /* all 0 */
                for (int a = 0; a < 3; a++) o[a] = b[a] << v->slog2;
                copy_part(v, L, e, o, lo, raw);
            }
    return 0;
}

/* Some non-zero voxel of level-0 brick b (entry e) outside volume, in at.
 * A packed record is unpacked into buf (S^3 voxels; NULL: none) once,
 * not read a voxel at a time (each a rank over its masks): the edge
 * bricks of a distance field are all records, and read voxel by voxel
 * they were the dragon's largest serial window at 1024^3 (60-70 ms). */
static bool brick_outside(const vod_volume *v, const uint32_t b[3], uint32_t e,
                          const uint32_t volume[3], uint32_t *buf, uint32_t at[3])
{
    uint32_t S = v->sbrick, m = v->slog2;
    bool unpacked = buf && v->packed && is_alloc(e);
    if (unpacked) vod_pack_range(v, brick_data(v, e), 0, (size_t)S * S * S, buf);
    for (uint32_t z = 0; z < S; z++)
        for (uint32_t y = 0; y < S; y++)
            for (uint32_t x = 0; x < S; x++) {
                uint32_t p[3] = {(b[0] << m) + x, (b[1] << m) + y, (b[2] << m) + z};
                if (p[0] < volume[0] && p[1] < volume[1] && p[2] < volume[2])
                    continue;
                size_t i = vox_index(v, x, y, z);
                if (is_alloc(e) && !(unpacked ? buf[i] : brick_voxel(v, e, i)))
                    continue;
                memcpy(at, p, sizeof p);
                return true;
            }
    return false;
}

/* vol_outside's scan: the rows of level-0 bricks (one (y, z) each, row r
 * = z * grid[1] + y) on several threads when there are many bricks to
 * look at, dealt round robin (the edge bricks lie in the last rows, the
 * grid's far face in z, and in every grid[1]-th: contiguous parts would
 * give most of them to one thread).  Each part stops at its first find;
 * the answer is the lowest row's, the voxel the one-thread scan finds. */
typedef struct {
    const vod_volume *v;
    const uint32_t *volume;
    uint64_t rows;
    _Atomic uint64_t first; /* the lowest row with a find so far */
    uint64_t row[PAR_MAX];  /* each part's find, UINT64_MAX: none */
    uint32_t at[PAR_MAX][3];
} outside_scan;

/* A (y, z) row whose bricks all lie inside volume on y and z is scanned
 * from the first brick that reaches past it on x. */
static bool row_outside(const vod_volume *v, const uint32_t volume[3], uint64_t r,
                        uint32_t *buf, uint32_t at[3])
{
    const uint32_t *g = v->grid[0];
    uint32_t m = v->slog2, b[3] = {0, (uint32_t)(r % g[1]), (uint32_t)(r / g[1])};
    bool in_yz = ((uint64_t)b[2] + 1) << m <= volume[2] && ((uint64_t)b[1] + 1) << m <= volume[1];
    for (b[0] = in_yz ? volume[0] >> m : 0; b[0] < g[0]; b[0]++) {
        uint32_t e = entry_at(v, 0, b);
        bool inside = in_yz && ((uint64_t)b[0] + 1) << m <= volume[0];
        if (e && !inside && brick_outside(v, b, e, volume, buf, at)) return true;
    }
    return false;
}

static void outside_part(void *ud, unsigned k, unsigned n)
{
    outside_scan *sc = ud;
    const vod_volume *v = sc->v;
    size_t S = v->sbrick;
    /* no buffer: each voxel read from its record (slower, never wrong) */
    uint32_t *buf = v->packed ? malloc(S * S * S * sizeof *buf) : NULL;
    sc->row[k] = UINT64_MAX;
    for (uint64_t r = k; r < sc->rows; r += n) {
        /* relaxed: a hint that lets a part stop early; the join orders
         * the parts' finds before they are read */
        if (r > atomic_load_explicit(&sc->first, memory_order_relaxed)) break;
        if (!row_outside(v, sc->volume, r, buf, sc->at[k])) continue;
        sc->row[k] = r;
        uint64_t f = atomic_load_explicit(&sc->first, memory_order_relaxed);
        while (r < f && !atomic_compare_exchange_weak_explicit(&sc->first, &f, r,
                                                               memory_order_relaxed,
                                                               memory_order_relaxed)) {
        }
        break;
    }
    free(buf);
}

/* Bricks to look at below which one thread scans the rows (a thread
 * costs more than a few thousand table entries). */
#define OUTSIDE_PAR_BRICKS 16384u

/* The level-0 bricks the scan looks at: every brick of the rows that reach
 * past volume on y or z, the rest of the rows from volume's x edge on. */
static uint64_t outside_bricks(const vod_volume *v, const uint32_t volume[3])
{
    const uint32_t *g = v->grid[0];
    uint32_t m = v->slog2, in[3];
    for (int a = 0; a < 3; a++) in[a] = volume[a] >> m < g[a] ? volume[a] >> m : g[a];
    uint64_t rows = (uint64_t)g[1] * g[2], inner = (uint64_t)in[1] * in[2];
    return (rows - inner) * g[0] + inner * (g[0] - in[0]);
}

/* Only level-0 bricks that reach past volume are scanned, voxel by voxel. */
static int vol_outside(const vod_source *s, const uint32_t volume[3],
                       uint32_t at[3])
{
    const vod_volume *v = s->ctx;
    const uint32_t *g = v->grid[0];
    outside_scan sc = {.v = v, .volume = volume, .rows = (uint64_t)g[1] * g[2]};
    atomic_init(&sc.first, UINT64_MAX);
    unsigned n = outside_bricks(v, volume) >= OUTSIDE_PAR_BRICKS ? par_cpus() : 1;
    if (n > 1) par_run(n, outside_part, &sc);
    else outside_part(&sc, 0, 1);
    unsigned best = 0;
    for (unsigned k = 1; k < n; k++)
        if (sc.row[k] < sc.row[best]) best = k;
    if (sc.row[best] == UINT64_MAX) return 0;
    memcpy(at, sc.at[best], sizeof sc.at[best]);
    return 1;
}

static const vod_source_ops volume_ops = {
    .name = "volume",
    .prepare = vol_prepare,
    .outside = vol_outside,
    .region = vol_region,
    .fill = vol_fill,
};

vod_source vod_volume_source(vod_volume *v)
{
    return (vod_source){
        .ops = &volume_ops,
        .ctx = v,
        .depth = v->depth,
        .channels = channels_of(v),
    };
}
