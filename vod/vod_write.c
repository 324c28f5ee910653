/* VOD writer (docs/vod-format.md): plan (layout, aggregate, collect),
 * encode bricks, assemble the file.  See vod.h for the three phases. */
#include "vod.h"

#include <errno.h>
#include <math.h>
#include <stdarg.h>
#include <stdbool.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>
#include <zlib.h>

#include "voxel.h"

#define TRAILER_FIXED 40u /* trailer bytes besides the metadata */
#define WBUF_BYTES (256u << 10)

__attribute__((format(printf, 4, 5))) static int
fail(char *err, size_t errlen, int rc, const char *fmt, ...)
{
    if (err && errlen) {
        va_list ap;
        va_start(ap, fmt);
        vsnprintf(err, errlen, fmt, ap);
        va_end(ap);
    }
    return rc;
}

/* A FourCC as text for messages ("ZLIB"; '?' for unprintable bytes). */
static const char *fourcc_str(uint32_t v, char buf[5])
{
    for (int i = 0; i < 4; i++) {
        char c = (char)(v >> (8 * i));
        buf[i] = (c >= 32 && c < 127) ? c : '?';
    }
    buf[4] = '\0';
    return buf;
}

void vod_params_default(vod_params *p)
{
    memset(p, 0, sizeof *p);
    p->brick = VOD_DEFAULT_BRICK;
    p->channel = VOXEL_CH_SURFACE;
    p->comp = VOD_COMP_ZLIB;
    p->hash = VOD_HASH_SFHS;
    p->zlib_level = 6;
    for (int a = 0; a < 3; a++) p->voxel_scale[a] = 1.0f;
}

static int check_geometry(const vod_params *p, char *err, size_t errlen)
{
    const uint32_t *v = p->volume;
    if (!v[0] || !v[1] || !v[2])
        return fail(err, errlen, -EINVAL,
                    "volumeSize %ux%ux%u: each side must be at least 1", v[0],
                    v[1], v[2]);
    if (p->brick < 2 || p->brick > 256 || (p->brick & (p->brick - 1)))
        return fail(err, errlen, -EINVAL,
                    "brickSize %u is not a power of two in 2..256", p->brick);
    for (int a = 0; a < 3; a++) {
        if (!isfinite(p->voxel_scale[a]) || !(p->voxel_scale[a] > 0.0f))
            return fail(err, errlen, -EINVAL,
                        "voxelScale %g on axis %d must be finite and > 0",
                        (double)p->voxel_scale[a], a);
        if (!isfinite(p->origin[a]))
            return fail(err, errlen, -EINVAL, "origin on axis %d is not finite", a);
    }
    return 0;
}

static int check_encoding(const vod_params *p, char *err, size_t errlen)
{
    char b[5];
    if (p->channel != VOXEL_CH_SURFACE && p->channel != VOXEL_CH_OCCUPANCY)
        return fail(err, errlen, -EINVAL,
                    "channel %d cannot be written (1 occupancy or 3 surface)",
                    p->channel);
    if (p->comp != VOD_COMP_NONE && p->comp != VOD_COMP_ZLIB &&
        p->comp != VOD_COMP_RUNL)
        return fail(err, errlen, -EINVAL,
                    "compression '%s' unknown (NONE, ZLIB or RUNL)",
                    fourcc_str(p->comp, b));
    if (p->comp == VOD_COMP_ZLIB && (p->zlib_level < 1 || p->zlib_level > 9))
        return fail(err, errlen, -EINVAL, "zlib level %d outside 1..9",
                    p->zlib_level);
    if (p->hash != VOD_HASH_SFHS && p->hash != VOD_HASH_XX32)
        return fail(err, errlen, -EINVAL, "hash '%s' unknown (SFHS or XX32)",
                    fourcc_str(p->hash, b));
    size_t m = p->metadata ? strlen(p->metadata) : 0;
    if (m > VOD_MAX_METADATA)
        return fail(err, errlen, -EINVAL, "metadata of %zu bytes, more than %u",
                    m, VOD_MAX_METADATA);
    return 0;
}

int vod_layout_make(const vod_params *p, int octree_depth, vod_layout *L,
                    char *err, size_t errlen)
{
    int rc = check_geometry(p, err, errlen);
    if (rc == 0) rc = check_encoding(p, err, errlen);
    if (rc) return rc;
    if (octree_depth < 1 || octree_depth > OCTREE_MAX_DEPTH)
        return fail(err, errlen, -EINVAL, "octree depth %d outside 1..%d",
                    octree_depth, OCTREE_MAX_DEPTH);
    uint32_t maxv = p->volume[0];
    if (p->volume[1] > maxv) maxv = p->volume[1];
    if (p->volume[2] > maxv) maxv = p->volume[2];
    if (maxv > 1u << octree_depth)
        return fail(err, errlen, -EINVAL,
                    "volume side %u exceeds the octree's %u voxels per axis",
                    maxv, 1u << octree_depth);
    memset(L, 0, sizeof *L);
    L->brick = p->brick;
    while (1u << L->brick_log2 < p->brick) L->brick_log2++;
    /* treeHeight = 1 + ceil(log2(ceil(max(volume) / brick))) */
    uint32_t per_axis = (maxv + p->brick - 1) / p->brick, m = 0;
    while (1u << m < per_axis) m++;
    L->height = 1 + m;
    L->padded = p->brick << m;
    L->voxel_bits = p->channel == VOXEL_CH_OCCUPANCY ? 1 : 32;
    L->raw_bytes = (size_t)p->brick * p->brick * p->brick * L->voxel_bits / 8;
    L->nodes = ((1ull << (3 * L->height)) - 1) / 7;
    L->octree_depth = octree_depth;
    if (VOD_HEADER_BYTES + L->nodes * 4 + 4 > UINT32_MAX)
        return fail(err, errlen, -EFBIG,
                    "octree table of %llu nodes (treeHeight %u) passes the 4 GiB "
                    "limit of VOD's u32 offsets; use a larger brick",
                    (unsigned long long)L->nodes, L->height);
    return 0;
}

/* ---- the volume precondition ---- */

/* Some voxel below cell c (height h, low corner o), which holds one. */
static void first_voxel(const octree *t, uint32_t c, int h, uint32_t o[3])
{
    for (;;) {
        unsigned i = 0;
        while (i < 7 && !t->cells[c].child[i]) i++;
        for (int a = 0; a < 3; a++) o[a] += ((i >> a) & 1u) << h;
        if (h == 0) return;
        c = t->cells[c].child[i];
        h--;
    }
}

/* Only cells that straddle a high face are opened; a cell wholly inside the
 * volume is skipped, one wholly outside is an error if it holds anything. */
static int check_cell(const octree *t, const uint32_t *vol, uint32_t c, int h,
                      const uint32_t o[3], uint32_t bad[3])
{
    uint64_t side = 2ull << h;
    if (o[0] + side <= vol[0] && o[1] + side <= vol[1] && o[2] + side <= vol[2])
        return 0;
    for (unsigned i = 0; i < 8; i++) {
        uint32_t e = t->cells[c].child[i], co[3];
        if (!e) continue;
        for (int a = 0; a < 3; a++) co[a] = o[a] + (((i >> a) & 1u) << h);
        bool out = co[0] >= vol[0] || co[1] >= vol[1] || co[2] >= vol[2];
        if (out) {
            if (h > 0) first_voxel(t, e, h - 1, co);
            memcpy(bad, co, sizeof co);
            return -EINVAL;
        }
        if (h > 0 && check_cell(t, vol, e, h - 1, co, bad)) return -EINVAL;
    }
    return 0;
}

int vod_check_volume(const octree *t, const uint32_t volume[3], char *err,
                     size_t errlen)
{
    uint32_t o[3] = {0, 0, 0}, bad[3];
    if (t->used < 2) return 0;
    if (check_cell(t, volume, 1, t->depth - 1, o, bad) == 0) return 0;
    return fail(err, errlen, -EINVAL,
                "the octree holds a voxel at %u,%u,%u, outside volumeSize "
                "%ux%ux%u (VOD padding must be 0)",
                bad[0], bad[1], bad[2], volume[0], volume[1], volume[2]);
}

/* ---- phase 1: aggregate ---- */

/* Channel 3 (spec section 3): occupancy is the mean rounded half up, the
 * normal the normalized sum of the normals of the occupied children. */
static uint32_t down_surface(const uint32_t v[8])
{
    uint32_t sum = 0;
    double n[3] = {0, 0, 0};
    for (int i = 0; i < 8; i++) {
        uint32_t occ = voxel_occupancy(v[i]);
        if (!occ) continue;
        double m[3];
        voxel_unpack_normal(v[i], m);
        sum += occ;
        for (int a = 0; a < 3; a++) n[a] += m[a];
    }
    uint32_t occ = (sum + 4) / 8;
    if (occ == 0) return 0;
    double len = sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
    if (len > 0)
        for (int a = 0; a < 3; a++) n[a] /= len;
    return occ | voxel_pack_normal(n);
}

static uint32_t downsample(const uint32_t v[8], int channel)
{
    if (channel == VOXEL_CH_SURFACE) return down_surface(v);
    return (v[0] | v[1] | v[2] | v[3] | v[4] | v[5] | v[6] | v[7]) != 0;
}

static void agg_cell(octree *t, uint32_t c, int h, int channel)
{
    uint32_t v[8];
    for (int i = 0; i < 8; i++) {
        uint32_t e = t->cells[c].child[i];
        if (h > 0 && e) agg_cell(t, e, h - 1, channel);
        v[i] = h == 0 ? e : e ? t->agg[e] : 0;
    }
    t->agg[c] = downsample(v, channel);
}

void vod_aggregate(octree *t, int channel)
{
    if (!t->agg || t->used < 2) return;
    t->agg[0] = 0;
    agg_cell(t, 1, t->depth - 1, channel);
}

/* ---- phase 1: collect ---- */

/* The cell covering node (level, b) and its height; 0 if none.  A node's
 * region is a cell of height brick_log2 + level - 1, except a root brick
 * larger than the whole octree (treeHeight 1), which holds the root cell. */
static uint32_t node_cell(const octree *t, const vod_layout *L, uint32_t level,
                          const uint32_t b[3], int *h)
{
    int hc = (int)(L->brick_log2 + level) - 1;
    if (hc > t->depth - 1) {
        *h = t->depth - 1;
        return 1;
    }
    *h = hc;
    int s = (int)(L->brick_log2 + level);
    return octree_find(t, hc, b[0] << s, b[1] << s, b[2] << s);
}

static bool cell_empty(const octree *t, uint32_t c)
{
    if (!c) return true;
    for (int i = 0; i < 8; i++)
        if (t->cells[c].child[i]) return false;
    return true;
}

typedef struct {
    const octree *t;
    vod_node *out;
    size_t cap, n;
    uint64_t sub[32]; /* nodes in a subtree rooted at level l */
} collect_ctx;

/* A node of level >= 1 is a cell of height >= brick_log2 >= 1, whose
 * children are the cells of its 8 child nodes. */
static void collect_node(collect_ctx *x, uint32_t c, uint32_t level,
                         uint64_t pre, const uint32_t b[3])
{
    if (cell_empty(x->t, c)) return;
    if (x->n < x->cap)
        x->out[x->n] = (vod_node){pre, level, b[0], b[1], b[2]};
    x->n++;
    if (level == 0) return;
    for (unsigned i = 0; i < 8; i++) {
        uint32_t cb[3];
        for (int a = 0; a < 3; a++) cb[a] = b[a] << 1 | ((i >> a) & 1u);
        collect_node(x, x->t->cells[c].child[i], level - 1,
                     pre + 1 + i * x->sub[level - 1], cb);
    }
}

size_t vod_collect(const octree *t, const vod_layout *L, vod_node *out,
                   size_t cap)
{
    collect_ctx x = {.t = t, .out = out, .cap = out ? cap : 0};
    for (uint32_t l = 0; l < L->height && l < 31; l++)
        x.sub[l] = ((1ull << (3 * (l + 1))) - 1) / 7;
    uint32_t b[3] = {0, 0, 0};
    int h;
    uint32_t root = node_cell(t, L, L->height - 1, b, &h);
    collect_node(&x, root, L->height - 1, 0, b);
    return x.n;
}

/* ---- phase 2: encode ---- */

typedef struct {
    const octree *t;
    uint8_t *raw;
    uint32_t brick, bits, level;
} fill_ctx;

static inline void put_voxel(const fill_ctx *f, uint32_t x, uint32_t y,
                             uint32_t z, uint32_t v)
{
    size_t i = ((size_t)z * f->brick + y) * f->brick + x;
    if (f->bits == 32)
        vod_put32(f->raw + 4 * i, v);
    else if (v)
        f->raw[i >> 3] |= (uint8_t)(1u << (i & 7));
}

/* Cell c of height h has its low corner at level-l voxel (x, y, z) of the
 * brick.  Its children cover 2^(h-l) level-l voxels each: at h == l every
 * child is one voxel (a voxel value at level 0, the child's agg above). */
static void fill(const fill_ctx *f, uint32_t c, int h, uint32_t x, uint32_t y,
                 uint32_t z)
{
    const uint32_t *e = f->t->cells[c].child;
    if (h == (int)f->level) {
        for (unsigned i = 0; i < 8; i++) {
            uint32_t v = f->level == 0 ? e[i] : e[i] ? f->t->agg[e[i]] : 0;
            if (v) put_voxel(f, x + (i & 1u), y + ((i >> 1) & 1u),
                             z + ((i >> 2) & 1u), v);
        }
        return;
    }
    uint32_t half = 1u << (h - (int)f->level);
    for (unsigned i = 0; i < 8; i++)
        if (e[i])
            fill(f, e[i], h - 1, x + (i & 1u) * half, y + ((i >> 1) & 1u) * half,
                 z + ((i >> 2) & 1u) * half);
}

/* zlib's bound for a deflate stream whose parameters are not the defaults
 * (deflateBound's conservative case), plus the zlib wrapper. */
size_t vod_encode_bound(const vod_layout *L, const vod_params *p)
{
    size_t n = L->raw_bytes;
    if (p->comp == VOD_COMP_ZLIB)
        return n + ((n + 7) >> 3) + ((n + 63) >> 6) + 5 + 6 + 16;
    if (p->comp == VOD_COMP_RUNL) return vod_runl_bound(L->voxel_bits, n);
    return n;
}

/* One deflate stream per thread, reset between bricks: deflateInit's
 * allocations and table clearing cost more than compressing a small brick
 * (an 8^3 brick: compress2 ~170 us, deflateReset + deflate ~25 us).  The
 * window is the smallest that holds a whole brick, so the output is the
 * same as with a 32 KiB window, less the header's window size. */
static _Thread_local struct {
    z_stream z;
    int level, wbits, live;
} zc;

void vod_encode_cleanup(void)
{
    if (zc.live) deflateEnd(&zc.z);
    zc.live = 0;
}

static int zlib_stream(int level, int wbits)
{
    if (zc.live && zc.level == level && zc.wbits == wbits)
        return deflateReset(&zc.z) == Z_OK ? 0 : -EIO;
    vod_encode_cleanup();
    memset(&zc.z, 0, sizeof zc.z);
    int zr = deflateInit2(&zc.z, level, Z_DEFLATED, wbits, 8, Z_DEFAULT_STRATEGY);
    if (zr != Z_OK) return zr == Z_MEM_ERROR ? -ENOMEM : -EINVAL;
    zc.live = 1;
    zc.level = level;
    zc.wbits = wbits;
    return 0;
}

static int zlib_brick(const uint8_t *raw, size_t n, int level, uint8_t *out,
                      size_t cap, uint32_t *size)
{
    int wbits = 9;
    while (wbits < 15 && ((size_t)1 << wbits) < n) wbits++;
    int rc = zlib_stream(level, wbits);
    if (rc) return rc;
    zc.z.next_in = (Bytef *)raw;
    zc.z.avail_in = (uInt)n;
    zc.z.next_out = out;
    zc.z.avail_out = cap > UINT32_MAX ? UINT32_MAX : (uInt)cap;
    if (deflate(&zc.z, Z_FINISH) != Z_STREAM_END) return -ENOBUFS;
    *size = (uint32_t)zc.z.total_out;
    return 0;
}

static int compress_brick(const vod_layout *L, const vod_params *p,
                          const uint8_t *raw, uint8_t *out, size_t cap,
                          uint32_t *size)
{
    size_t n = L->raw_bytes;
    if (p->comp == VOD_COMP_ZLIB)
        return zlib_brick(raw, n, p->zlib_level, out, cap, size);
    if (p->comp == VOD_COMP_RUNL) {
        size_t o = vod_runl_encode(L->voxel_bits, raw, n, out, cap);
        if (!o) return -ENOBUFS;
        *size = (uint32_t)o;
        return 0;
    }
    if (cap < n) return -ENOBUFS;
    memcpy(out, raw, n);
    *size = (uint32_t)n;
    return 0;
}

int vod_encode(const octree *t, const vod_layout *L, const vod_params *p,
               const vod_node *n, uint8_t *scratch, uint8_t *out, size_t cap,
               vod_encoded *rec)
{
    if (n->level >= L->height) return -EINVAL;
    uint32_t per_axis = L->padded >> (L->brick_log2 + n->level);
    if (n->bx >= per_axis || n->by >= per_axis || n->bz >= per_axis) return -EINVAL;
    if (n->level > 0 && !t->agg) return -EINVAL;
    memset(scratch, 0, L->raw_bytes);
    fill_ctx f = {t, scratch, L->brick, L->voxel_bits, n->level};
    uint32_t b[3] = {n->bx, n->by, n->bz};
    int h;
    uint32_t c = node_cell(t, L, n->level, b, &h);
    if (c) fill(&f, c, h, 0, 0, 0);
    rec->hash = vod_hash(p->hash, scratch, L->raw_bytes);
    return compress_brick(L, p, scratch, out, cap, &rec->size);
}

/* ---- phase 3: assemble ---- */

/* Buffered output that keeps the running CRC-32 of all bytes written. */
typedef struct {
    vod_sink *sink;
    uint8_t *buf;
    size_t len;
    uint32_t crc;
    uint64_t total;
    uint32_t file_crc; /* the trailer's fileCRC32, once written */
    int err;
} wbuf;

static void wb_flush(wbuf *w)
{
    if (w->err || w->len == 0) return;
    w->crc = (uint32_t)crc32(w->crc, w->buf, (uInt)w->len);
    int rc = w->sink->write(w->sink->ud, w->buf, w->len);
    if (rc < 0) w->err = rc;
    w->total += w->len;
    w->len = 0;
}

static void wb_put(wbuf *w, const void *p, size_t n)
{
    const uint8_t *s = p;
    while (n && !w->err) {
        size_t k = WBUF_BYTES - w->len < n ? WBUF_BYTES - w->len : n;
        memcpy(w->buf + w->len, s, k);
        w->len += k;
        s += k;
        n -= k;
        if (w->len == WBUF_BYTES) wb_flush(w);
    }
}

static void wb_u32(wbuf *w, uint32_t v)
{
    uint8_t b[4];
    vod_put32(b, v);
    wb_put(w, b, 4);
}

/* Empty subtrees of the octree table go out as runs of zeros. */
static void wb_zeros(wbuf *w, uint64_t n)
{
    while (n && !w->err) {
        size_t k = WBUF_BYTES - w->len;
        if (k > n) k = (size_t)n;
        memset(w->buf + w->len, 0, k);
        w->len += k;
        n -= k;
        if (w->len == WBUF_BYTES) wb_flush(w);
    }
}

static uint32_t f32_bits(float f)
{
    uint32_t u;
    memcpy(&u, &f, sizeof u);
    return u;
}

static void put_header(wbuf *w, const vod_layout *L, const vod_params *p)
{
    uint8_t h[VOD_HEADER_BYTES];
    uint32_t flags = VOD_FLAG_TRAILER;
    if (p->comp != VOD_COMP_NONE) flags |= VOD_FLAG_COMPRESSED;
    for (int a = 0; a < 3; a++)
        if (L->padded > p->volume[a]) flags |= VOD_FLAG_PADDED;
    memcpy(h, ".VOD", 4);
    vod_put32(h + 4, 1);
    for (int a = 0; a < 3; a++) {
        vod_put32(h + 8 + 4 * a, p->volume[a]);
        vod_put32(h + 20 + 4 * a, L->brick);
        vod_put32(h + 32 + 4 * a, f32_bits(p->voxel_scale[a]));
    }
    vod_put32(h + 44, L->height);
    vod_put32(h + 48, L->voxel_bits);
    vod_put32(h + 52, p->hash);
    vod_put32(h + 56, p->comp);
    vod_put32(h + 60, flags);
    wb_put(w, h, sizeof h);
}

/* Section 7; the CRC covers every byte before its own field. */
static void put_trailer(wbuf *w, const vod_params *p, size_t meta)
{
    uint32_t at = (uint32_t)(w->total + w->len);
    wb_put(w, "VODX", 4);
    wb_u32(w, TRAILER_FIXED + (uint32_t)meta);
    for (int a = 0; a < 3; a++) wb_u32(w, f32_bits(p->origin[a]));
    wb_u32(w, (uint32_t)p->channel);
    wb_u32(w, (uint32_t)meta);
    wb_put(w, p->metadata, meta);
    wb_u32(w, at);
    wb_put(w, "XDOV", 4);
    wb_flush(w);
    w->file_crc = w->crc;
    wb_u32(w, w->file_crc);
    wb_flush(w);
}

/* IDs 1..u by first use.  Candidates come from the hash; a match is
 * confirmed by comparing the encoded bytes.  That is the same as comparing
 * the raw bricks: every brick of a file is encoded by the same
 * deterministic function of its raw bytes (same algorithm, same zlib
 * level), so equal raw bricks give equal encodings, and decoding is a
 * function, so equal encodings come from equal raw bricks.  Equal hashes
 * alone never merge. */
static int dedup(size_t n, const vod_encoded *recs, const uint8_t *const *data,
                 uint32_t *ids, uint32_t *first, uint32_t *unique)
{
    size_t cap = 16;
    while (cap < 2 * n) cap *= 2;
    uint32_t *slot = calloc(cap, sizeof *slot), u = 0;
    if (!slot) return -ENOMEM;
    for (size_t i = 0; i < n; i++) {
        uint32_t h = recs[i].hash;
        for (size_t j = (h ^ h >> 15) & (cap - 1);; j = (j + 1) & (cap - 1)) {
            uint32_t s = slot[j];
            if (!s) {
                slot[j] = ids[i] = ++u;
                first[u - 1] = (uint32_t)i;
                break;
            }
            const uint32_t k = first[s - 1];
            if (recs[k].hash == h && recs[k].size == recs[i].size &&
                memcmp(data[k], data[i], recs[i].size) == 0) {
                ids[i] = s;
                break;
            }
        }
    }
    free(slot);
    *unique = u;
    return 0;
}

static int check_inputs(const vod_layout *L, const vod_params *p, size_t n,
                        const vod_node *nodes, const vod_encoded *recs,
                        const uint8_t *const *data)
{
    size_t bound = vod_encode_bound(L, p);
    if (n > UINT32_MAX - 1) return -EFBIG;
    for (size_t i = 0; i < n; i++) {
        if (nodes[i].preorder >= L->nodes) return -EINVAL;
        if (i && nodes[i].preorder <= nodes[i - 1].preorder) return -EINVAL;
        if (recs[i].size > bound || (recs[i].size && !data[i])) return -EINVAL;
    }
    return 0;
}

static void write_body(wbuf *w, const vod_layout *L, const vod_params *p,
                       size_t n, const vod_node *nodes, const vod_encoded *recs,
                       const uint8_t *const *data, const uint32_t *ids,
                       const uint32_t *first, uint32_t u)
{
    put_header(w, L, p);
    uint64_t at = 0; /* octree table: zeros between the non-empty nodes */
    for (size_t i = 0; i < n; i++) {
        wb_zeros(w, 4 * (nodes[i].preorder - at));
        wb_u32(w, ids[i]);
        at = nodes[i].preorder + 1;
    }
    wb_zeros(w, 4 * (L->nodes - at));
    wb_u32(w, u);
    uint64_t off = VOD_HEADER_BYTES + 4 * L->nodes + 4 + 12ull * u;
    for (uint32_t j = 0; j < u; j++) {
        wb_u32(w, j + 1);
        wb_u32(w, (uint32_t)off);
        wb_u32(w, recs[first[j]].hash);
        off += 4 + (uint64_t)recs[first[j]].size;
    }
    for (uint32_t j = 0; j < u; j++) {
        wb_u32(w, recs[first[j]].size);
        wb_put(w, data[first[j]], recs[first[j]].size);
    }
}

static void fill_stats(vod_stats *st, const vod_layout *L, size_t n,
                       const vod_encoded *recs, const uint32_t *first,
                       uint32_t u, const wbuf *w)
{
    uint64_t side = L->padded;
    memset(st, 0, sizeof *st);
    st->file_bytes = w->total;
    st->raw_bytes = side * side * side * L->voxel_bits / 8;
    st->nodes = L->nodes;
    st->nonempty_nodes = n;
    st->bricks = u;
    st->brick_raw_bytes = (uint64_t)u * L->raw_bytes;
    for (uint32_t j = 0; j < u; j++) st->brick_data_bytes += recs[first[j]].size;
    st->crc32 = w->file_crc;
}

/* The 4 GiB limit, with what to ask for instead. */
static int too_big(char *err, size_t errlen, const vod_layout *L, const vod_params *p,
                   uint32_t unique)
{
    return fail(err, errlen, -EFBIG,
                "the VOD file would pass 4 GiB, the limit of the format's 32-bit "
                "offsets (%u unique bricks of %u^3 voxels); ask for %s",
                unique, L->brick,
                p->comp == VOD_COMP_NONE ? "compression (zlib or runl), a larger brick "
                                           "or a lower res"
                                         : "a larger brick or a lower res");
}

int vod_assemble(const vod_layout *L, const vod_params *p, size_t n,
                 const vod_node *nodes, const vod_encoded *recs,
                 const uint8_t *const *data, vod_sink *sink, vod_stats *st,
                 char *err, size_t errlen)
{
    if (errlen) err[0] = '\0';
    int rc = check_inputs(L, p, n, nodes, recs, data);
    if (rc)
        return fail(err, errlen, rc, "bricks out of preorder or over their bound");
    uint32_t *ids = malloc((n + 1) * sizeof *ids);
    uint32_t *first = malloc((n + 1) * sizeof *first), u = 0;
    wbuf w = {.sink = sink, .buf = malloc(WBUF_BYTES)};
    rc = ids && first && w.buf ? dedup(n, recs, data, ids, first, &u) : -ENOMEM;
    size_t meta = p->metadata ? strlen(p->metadata) : 0;
    uint64_t size = VOD_HEADER_BYTES + 4 * L->nodes + 4 + 12ull * u +
                    TRAILER_FIXED + meta;
    for (uint32_t j = 0; j < u && !rc; j++) size += 4 + (uint64_t)recs[first[j]].size;
    if (rc) fail(err, errlen, rc, "out of memory for %zu bricks", n);
    else if (size > UINT32_MAX) rc = too_big(err, errlen, L, p, u);
    if (!rc) {
        write_body(&w, L, p, n, nodes, recs, data, ids, first, u);
        put_trailer(&w, p, meta);
        rc = w.err;
    }
    if (!rc && st) fill_stats(st, L, n, recs, first, u, &w);
    free(ids);
    free(first);
    free(w.buf);
    return rc;
}

/* ---- all three phases ---- */

/* Phase 2 for every node, serially, into one buffer (offsets in off). */
static int encode_all(const octree *t, const vod_layout *L, const vod_params *p,
                      size_t n, const vod_node *nodes, vod_encoded *recs,
                      size_t *off, vod_membuf *b)
{
    size_t bound = vod_encode_bound(L, p);
    uint8_t *scratch = malloc(L->raw_bytes), *tmp = malloc(bound);
    int rc = scratch && tmp ? 0 : -ENOMEM;
    for (size_t i = 0; i < n && !rc; i++) {
        rc = vod_encode(t, L, p, &nodes[i], scratch, tmp, bound, &recs[i]);
        off[i] = b->n;
        if (!rc) rc = vod_mem_write(b, tmp, recs[i].size);
    }
    free(scratch);
    free(tmp);
    vod_encode_cleanup();
    return rc;
}

static int write_planned(octree *t, const vod_layout *L, const vod_params *p,
                         vod_sink *sink, vod_stats *st, char *err, size_t errlen)
{
    size_t n = vod_collect(t, L, NULL, 0);
    vod_node *nodes = malloc((n + 1) * sizeof *nodes);
    vod_encoded *recs = malloc((n + 1) * sizeof *recs);
    size_t *off = malloc((n + 1) * sizeof *off);
    const uint8_t **data = malloc((n + 1) * sizeof *data);
    vod_membuf b = {0};
    int rc = nodes && recs && off && data ? 0 : -ENOMEM;
    if (!rc) {
        vod_collect(t, L, nodes, n);
        rc = encode_all(t, L, p, n, nodes, recs, off, &b);
    }
    if (!rc) {
        for (size_t i = 0; i < n; i++) data[i] = b.p + off[i];
        rc = vod_assemble(L, p, n, nodes, recs, data, sink, st, err, errlen);
    }
    free(nodes);
    free(recs);
    free(off);
    free(data);
    free(b.p);
    return rc;
}

int vod_write_octree(octree *t, const vod_params *p, vod_sink *sink,
                     vod_stats *st, char *err, size_t errlen)
{
    vod_layout L;
    int rc = vod_layout_make(p, t->depth, &L, err, errlen);
    if (rc == 0) rc = vod_check_volume(t, p->volume, err, errlen);
    if (rc) return rc;
    uint32_t *own = NULL;
    if (!t->agg) {
        own = t->agg = malloc((size_t)t->used * sizeof *t->agg);
        if (!own)
            return fail(err, errlen, -ENOMEM, "out of memory for %u cells", t->used);
    }
    vod_aggregate(t, p->channel);
    if (errlen) err[0] = '\0';
    rc = write_planned(t, &L, p, sink, st, err, errlen);
    if (own) {
        free(own);
        t->agg = NULL;
    }
    /* vod_assemble's own failures are said; the sink's and the encoder's
     * are not yet */
    if (rc && (!errlen || !err[0]))
        return fail(err, errlen, rc, "cannot write the VOD file: %s", strerror(-rc));
    return rc;
}

int vod_mem_write(void *membuf, const void *buf, size_t n)
{
    vod_membuf *m = membuf;
    if (m->cap - m->n < n) {
        size_t cap = m->cap ? m->cap : 1 << 16;
        while (cap - m->n < n) {
            if (cap > SIZE_MAX / 2) return -ENOMEM;
            cap *= 2;
        }
        uint8_t *p = realloc(m->p, cap);
        if (!p) return -ENOMEM;
        m->p = p, m->cap = cap;
    }
    memcpy(m->p + m->n, buf, n);
    m->n += n;
    return 0;
}

int vod_fd_write(void *fd_as_ptr, const void *buf, size_t n)
{
    int fd = (int)(intptr_t)fd_as_ptr;
    const uint8_t *p = buf;
    while (n) {
        ssize_t k = write(fd, p, n);
        if (k < 0 && errno == EINTR) continue;
        if (k <= 0) return k < 0 ? -errno : -EIO;
        p += k;
        n -= (size_t)k;
    }
    return 0;
}
