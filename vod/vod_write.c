/* VOD writer (docs/vod-format.md): plan (layout, check, prepare, collect),
 * encode bricks, over any brick source; the file assembled by
 * vod_assemble.c.  See vod.h for the three phases and what a source must
 * guarantee. */
#include "vod.h"

#include <errno.h>
#include <math.h>
#include <stdbool.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>
#include <time.h>

#include <libdeflate.h>
#include <xxhash.h>

#include "clock.h"
#include "err.h"
#include "huge.h"
#include "voxel.h"

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

static int check_geometry(const vod_params *p, err_info *err)
{
    const uint32_t *v = p->volume;
    if (!v[0] || !v[1] || !v[2])
        return err_set(err, -EINVAL,
                    "volumeSize %ux%ux%u: each side must be at least 1", v[0],
                    v[1], v[2]);
    if (p->brick < 2 || p->brick > 256 || (p->brick & (p->brick - 1)))
        return err_set(err, -EINVAL,
                    "brickSize %u is not a power of two in 2..256", p->brick);
    for (int a = 0; a < 3; a++) {
        if (!isfinite(p->voxel_scale[a]) || !(p->voxel_scale[a] > 0.0f))
            return err_set(err, -EINVAL,
                        "voxelScale %g on axis %d must be finite and > 0",
                        (double)p->voxel_scale[a], a);
        if (!isfinite(p->origin[a]))
            return err_set(err, -EINVAL, "origin on axis %d is not finite", a);
    }
    return 0;
}

static int check_encoding(const vod_params *p, err_info *err)
{
    char b[5];
    if (p->channel != VOXEL_CH_SURFACE && p->channel != VOXEL_CH_OCCUPANCY &&
        p->channel != VOXEL_CH_DENSITY && p->channel != VOXEL_CH_DISTANCE)
        return err_set(err, -EINVAL,
                    "channel %d cannot be written (1 occupancy, 2 density, 3 "
                    "surface or 4 distance)",
                    p->channel);
    if (p->comp != VOD_COMP_NONE && p->comp != VOD_COMP_ZLIB &&
        p->comp != VOD_COMP_RUNL)
        return err_set(err, -EINVAL,
                    "compression '%s' unknown (NONE, ZLIB or RUNL)",
                    vod_fourcc_str(p->comp, b));
    if (p->comp == VOD_COMP_ZLIB &&
        (p->zlib_level < 1 || p->zlib_level > VOD_ZLIB_LEVEL_MAX))
        return err_set(err, -EINVAL, "zlib level %d outside 1..%d",
                    p->zlib_level, VOD_ZLIB_LEVEL_MAX);
    if (p->hash != VOD_HASH_SFHS && p->hash != VOD_HASH_XX32)
        return err_set(err, -EINVAL, "hash '%s' unknown (SFHS or XX32)",
                    vod_fourcc_str(p->hash, b));
    size_t m = p->metadata ? strlen(p->metadata) : 0;
    if (m > VOD_MAX_METADATA)
        return err_set(err, -EINVAL, "metadata of %zu bytes, more than %u",
                    m, VOD_MAX_METADATA);
    return 0;
}

int vod_layout_make(const vod_params *p, int octree_depth, vod_layout *L,
                    err_info *err)
{
    int rc = check_geometry(p, err);
    if (rc == 0) rc = check_encoding(p, err);
    if (rc) return rc;
    if (octree_depth < 1 || octree_depth > OCTREE_MAX_DEPTH)
        return err_set(err, -EINVAL, "octree depth %d outside 1..%d",
                    octree_depth, OCTREE_MAX_DEPTH);
    uint32_t maxv = p->volume[0];
    if (p->volume[1] > maxv) maxv = p->volume[1];
    if (p->volume[2] > maxv) maxv = p->volume[2];
    if (maxv > 1u << octree_depth)
        return err_set(err, -EINVAL,
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
    L->voxel_bits = p->channel == VOXEL_CH_OCCUPANCY ? 1
                    : p->channel == VOXEL_CH_DENSITY ? 8
                                                     : 32;
    L->channel = p->channel;
    L->raw_bytes = (size_t)p->brick * p->brick * p->brick * L->voxel_bits / 8;
    L->nodes = ((1ull << (3 * L->height)) - 1) / 7;
    L->octree_depth = octree_depth;
    if (VOD_HEADER_BYTES + L->nodes * 4 + 4 > UINT32_MAX)
        return err_set(err, -EFBIG,
                    "octree table of %llu nodes (treeHeight %u) passes the 4 GiB "
                    "limit of VOD's u32 offsets; use a larger brick",
                    (unsigned long long)L->nodes, L->height);
    return 0;
}

/* ---- phase 1: check, prepare, collect ---- */

/* "1 and 3", "1, 2 and 3": the channels of a source's mask. */
static const char *channel_list(uint32_t mask, char *buf, size_t n)
{
    size_t at = 0;
    int k = 0, total = 0;
    for (uint32_t m = mask; m; m &= m - 1) total++;
    buf[0] = '\0';
    for (int c = 0; c < 32 && at < n; c++) {
        if (!(mask >> c & 1u)) continue;
        const char *sep = k == 0 ? "" : k == total - 1 ? " and " : ", ";
        int w = snprintf(buf + at, n - at, "%s%d", sep, c);
        if (w < 0) break;
        at += (size_t)w;
        k++;
    }
    return buf;
}

int vod_check_source(const vod_source *s, const vod_params *p, err_info *err)
{
    const uint32_t *v = p->volume;
    uint32_t bad[3];
    char list[64];
    if (p->channel < 0 || p->channel > 31 || !(s->channels >> p->channel & 1u))
        return err_set(err, -EINVAL,
                    "channel %d cannot be written from the %s (it gives channel%s %s)",
                    p->channel, s->ops->name,
                    (s->channels & (s->channels - 1)) ? "s" : "",
                    channel_list(s->channels, list, sizeof list));
    if (!s->ops->outside(s, v, bad)) return 0;
    return err_set(err, -EINVAL,
                "the %s holds a voxel at %u,%u,%u, outside volumeSize "
                "%ux%ux%u (VOD padding must be 0)",
                s->ops->name, bad[0], bad[1], bad[2], v[0], v[1], v[2]);
}

int vod_prepare(vod_source *s, const vod_layout *L, int channel, err_info *err)
{
    int rc = s->ops->prepare(s, L, channel);
    if (rc)
        return err_set(err, rc, "cannot prepare the mip levels of the %s: %s",
                    s->ops->name, strerror(-rc));
    return 0;
}

/* ---- phase 2: encode ---- */

/* The raw bytes of the first bricks an encoder compressed are kept up to
 * this many bytes, to compare a duplicate with; past it the earlier brick
 * is filled again for the comparison. */
#define RAW_CACHE_BYTES (8u << 20)

/* Bricks up to this many raw bytes are encoded VOD_ENCODE_BATCH at a time
 * (scratch for each); larger ones one at a time. */
#define BATCH_RAW_BYTES (256u << 10)

/* Uniform values whose brick an encoder keeps at hand: a distance field's
 * +w and -w, an occupancy's 1, a density's few. */
#define UNIFORM_KEPT 4

/* A brick the encoder has compressed: enough to compare a new brick of
 * the same key with it (its raw bytes, kept or filled again) and to
 * answer for its duplicates. */
typedef struct {
    uint64_t key;    /* XXH3-64 of the raw brick: the table's key */
    vod_node node;
    vod_encoded rec;
    uint64_t tag;
    size_t raw_at;   /* its raw bytes in the cache, or SIZE_MAX */
} seen_brick;

struct vod_encoder {
    vod_layout L;
    vod_params p;          /* metadata NULL: encoding does not use it */
    uint8_t *raw, *other;  /* a batch's bricks; an earlier one filled again */
    size_t batch;          /* bricks raw holds: VOD_ENCODE_BATCH, or 1 */
    struct libdeflate_compressor *ld; /* ZLIB: one per encoder, or NULL */
    vod_sparse *sparse;    /* ZLIB at levels 1..6 */
    size_t bound;          /* vod_encode_bound */
    seen_brick *seen;      /* the bricks compressed so far, by first use */
    size_t nseen, seen_cap;
    uint32_t *slot;        /* open addressing on the key: seen index + 1 */
    size_t slot_cap;       /* a power of two, at least 2 * nseen */
    uint8_t *cache;        /* raw bricks of seen, up to RAW_CACHE_BYTES */
    size_t cache_used;
    /* The bricks of uniform nodes met so far: value uvalue[k] is seen
     * brick useen[k] (nuniform of them; past UNIFORM_KEPT the oldest is
     * replaced), so that such a node is neither filled nor hashed again. */
    uint32_t uvalue[UNIFORM_KEPT], useen[UNIFORM_KEPT];
    unsigned nuniform;
    vod_times t;
};

void vod_encoder_free(vod_encoder *e)
{
    if (!e) return;
    if (e->ld) libdeflate_free_compressor(e->ld);
    vod_sparse_free(e->sparse);
    free(e->raw);
    free(e->other);
    free(e->seen);
    free(e->slot);
    free(e->cache);
    free(e);
}

/* The compressors for p: at the levels up to VOD_SPARSE_LEVEL the
 * one-pass encoder of vod_deflate.c (see there; voxbench deflate measures
 * it against zlib and libdeflate) for bricks up to VOD_SPARSE_MAX_BRICK,
 * and libdeflate at p's level for the others, made when first needed
 * (656 KiB at level 6, 8.6 MiB at 12). */
static int make_compressors(vod_encoder *e, const vod_layout *L, const vod_params *p)
{
    if (p->comp != VOD_COMP_ZLIB) return 0;
    if (p->zlib_level < 1 || p->zlib_level > VOD_ZLIB_LEVEL_MAX) return -EINVAL;
    if (p->zlib_level > VOD_SPARSE_LEVEL) return 0;
    int rc = vod_sparse_new(L->brick, L->voxel_bits, &e->sparse);
    return rc == -EINVAL ? 0 : rc; /* bricks too large for it: libdeflate */
}

int vod_encoder_new(const vod_layout *L, const vod_params *p, vod_encoder **out)
{
    vod_encoder *e = calloc(1, sizeof *e);
    *out = NULL;
    if (!e) return -ENOMEM;
    e->L = *L;
    e->p = *p;
    e->p.metadata = NULL;
    e->bound = vod_encode_bound(L, p);
    e->batch = L->raw_bytes <= BATCH_RAW_BYTES ? VOD_ENCODE_BATCH : 1;
    e->raw = malloc(e->batch * L->raw_bytes);
    e->other = malloc(L->raw_bytes);
    e->slot_cap = 1024;
    e->slot = calloc(e->slot_cap, sizeof *e->slot);
    int rc = e->raw && e->other && e->slot ? 0 : -ENOMEM;
    if (!rc) rc = make_compressors(e, L, p);
    if (rc) {
        vod_encoder_free(e);
        return rc;
    }
    *out = e;
    return 0;
}

void vod_encoder_times(const vod_encoder *e, vod_times *t)
{
    *t = e->t;
}

/* The bytes depend on the raw brick alone, not on cap: the one-pass
 * encoder's output is used when it fits the bound (and then fails for a
 * smaller cap), libdeflate's when it does not. */
static int compress_brick(vod_encoder *e, const uint8_t *raw, uint8_t *out,
                          size_t cap, uint32_t *size)
{
    size_t n = e->L.raw_bytes;
    if (e->p.comp == VOD_COMP_ZLIB) {
        if (e->sparse && cap >= e->bound) {
            size_t k = vod_sparse_compress(e->sparse, raw, n, out, e->bound);
            if (k) {
                *size = (uint32_t)k;
                return 0;
            }
        } else if (e->sparse) {
            return -ENOBUFS;
        }
        if (!e->ld && !(e->ld = libdeflate_alloc_compressor(e->p.zlib_level)))
            return -ENOMEM;
        size_t k = libdeflate_zlib_compress(e->ld, raw, n, out, cap);
        if (!k) return -ENOBUFS;
        *size = (uint32_t)k;
        return 0;
    }
    if (e->p.comp == VOD_COMP_RUNL) {
        size_t o = vod_runl_encode(e->L.voxel_bits, raw, n, out, cap);
        if (!o) return -ENOBUFS;
        *size = (uint32_t)o;
        return 0;
    }
    if (cap < n) return -ENOBUFS;
    memcpy(out, raw, n);
    *size = (uint32_t)n;
    return 0;
}

/* Every voxel of the raw brick v (channel 1: any non-zero v is 1; 8-bit
 * voxels take v's low byte). */
static void fill_uniform(const vod_layout *L, uint32_t v, uint8_t *raw)
{
    if (L->voxel_bits == 32) {
        for (size_t i = 0; i < L->raw_bytes; i += 4) vod_put32(raw + i, v);
        return;
    }
    int byte = L->voxel_bits == 1 ? (v ? 0xff : 0) : (int)(v & 0xffu);
    memset(raw, byte, L->raw_bytes);
}

/* Node n's raw brick into raw: made here for a uniform node, else from the
 * source. */
static int fill_node(const vod_encoder *e, const vod_source *s, const vod_node *n,
                     uint8_t *raw)
{
    if (n->level >= e->L.height) return -EINVAL;
    uint32_t per_axis = e->L.padded >> (e->L.brick_log2 + n->level);
    if (n->bx >= per_axis || n->by >= per_axis || n->bz >= per_axis) return -EINVAL;
    if (n->uniform) {
        fill_uniform(&e->L, n->value, raw);
        return 0;
    }
    memset(raw, 0, e->L.raw_bytes);
    return s->ops->fill(s, &e->L, n, raw);
}

static size_t slot_of(uint64_t key, size_t cap)
{
    return (size_t)(key ^ key >> 29) & (cap - 1);
}

/* An earlier brick equal to raw (XXH3-64 key): candidates by the key,
 * each compared byte for byte (from the cache, or filled again).  NULL if
 * none.  The table always has a free slot (remember() keeps it at most
 * half full), so the probe ends. */
static const seen_brick *find_seen(vod_encoder *e, const vod_source *s,
                                   uint64_t key, const uint8_t *raw, int *rc)
{
    size_t j = slot_of(key, e->slot_cap);
    for (; e->slot[j]; j = (j + 1) & (e->slot_cap - 1)) {
        const seen_brick *b = &e->seen[e->slot[j] - 1];
        if (b->key != key) continue;
        const uint8_t *old = e->other;
        if (b->raw_at != SIZE_MAX) old = e->cache + b->raw_at;
        else if ((*rc = fill_node(e, s, &b->node, e->other))) return NULL;
        if (!memcmp(old, raw, e->L.raw_bytes)) return b;
    }
    return NULL;
}

/* Keep the raw brick in the cache while it has room; its offset, or
 * SIZE_MAX. */
static size_t cache_raw(vod_encoder *e, const uint8_t *raw)
{
    size_t n = e->L.raw_bytes;
    if (n > RAW_CACHE_BYTES - e->cache_used) return SIZE_MAX;
    /* huge pages: filled once, front to back (huge.h) */
    if (!e->cache && !(e->cache = huge_malloc(RAW_CACHE_BYTES))) return SIZE_MAX;
    memcpy(e->cache + e->cache_used, raw, n);
    e->cache_used += n;
    return e->cache_used - n;
}

/* Twice the slots; 0, or -ENOMEM with the table as it was. */
static int grow_slots(vod_encoder *e)
{
    size_t cap = 2 * e->slot_cap;
    uint32_t *slot = calloc(cap, sizeof *slot);
    if (!slot) return -ENOMEM;
    for (size_t i = 0; i < e->nseen; i++) {
        size_t j = slot_of(e->seen[i].key, cap);
        while (slot[j]) j = (j + 1) & (cap - 1);
        slot[j] = (uint32_t)i + 1;
    }
    free(e->slot);
    e->slot = slot;
    e->slot_cap = cap;
    return 0;
}

/* The uniform values kept at hand: uvalue[0 .. uniform_kept(e)). */
static unsigned uniform_kept(const vod_encoder *e)
{
    return e->nuniform < UNIFORM_KEPT ? e->nuniform : UNIFORM_KEPT;
}

/* Uniform nodes of value u are seen brick i from now on. */
static void keep_uniform(vod_encoder *e, uint32_t u, size_t i)
{
    unsigned n = uniform_kept(e), k = 0;
    while (k < n && e->uvalue[k] != u) k++;
    if (k == n) k = e->nuniform++ % UNIFORM_KEPT; /* a free entry, or the oldest */
    e->uvalue[k] = u;
    e->useen[k] = (uint32_t)i;
}

/* Keep brick (n, rec, tag), not in the table yet.  A table that cannot
 * grow only loses the shortcut: a later duplicate is then compressed
 * again, and vod_assemble still stores it once. */
static void remember(vod_encoder *e, uint64_t key, const uint8_t *raw,
                     const vod_node *n, const vod_encoded *rec, uint64_t tag)
{
    if (e->nseen >= UINT32_MAX - 1) return;
    if (2 * (e->nseen + 1) > e->slot_cap && grow_slots(e)) return;
    if (e->nseen == e->seen_cap) {
        size_t cap = e->seen_cap ? 2 * e->seen_cap : 256;
        seen_brick *s = realloc(e->seen, cap * sizeof *s);
        if (!s) return;
        e->seen = s;
        e->seen_cap = cap;
    }
    size_t j = slot_of(key, e->slot_cap);
    while (e->slot[j]) j = (j + 1) & (e->slot_cap - 1);
    e->seen[e->nseen] = (seen_brick){key, *n, *rec, tag, cache_raw(e, raw)};
    e->slot[j] = (uint32_t)++e->nseen;
    if (n->uniform) keep_uniform(e, n->value, e->nseen - 1);
}

/* A uniform node of a value met before: its brick is that one's, without
 * filling or hashing it again (find_seen would give the same one: a
 * brick's bytes are in the table once). */
static const seen_brick *same_uniform(const vod_encoder *e, const vod_node *n)
{
    if (!n->uniform) return NULL;
    for (unsigned k = 0; k < uniform_kept(e); k++)
        if (e->uvalue[k] == n->value) return &e->seen[e->useen[k]];
    return NULL;
}

/* What vod_encoder_put_batch found for one brick of the batch. */
enum { BATCH_NEW = -1, BATCH_SEEN = -2 }; /* else: the index of its first */

/* A batch of vod_encoder_put_batch: each brick's finding and raw bytes'
 * key, and the caller's records and tags of the bricks they equal. */
typedef struct {
    int kind[VOD_ENCODE_BATCH];
    uint64_t key[VOD_ENCODE_BATCH];
    vod_encoded *rec;
    uint64_t *same;
} batch;

/* Brick i of a batch into kind[i]: a duplicate of a brick this encoder
 * kept before (BATCH_SEEN, its record and tag set), of an earlier new
 * brick of the batch (that one's index), or new (BATCH_NEW).  Its raw
 * bytes are filled into e->raw's slot i, their key into key[i]. */
static int batch_find(vod_encoder *e, const vod_source *s, const vod_node *n,
                      size_t i, batch *bt)
{
    int *kind = bt->kind;
    uint64_t *key = bt->key;
    size_t rb = e->L.raw_bytes;
    uint8_t *raw = e->raw + i * rb;
    const seen_brick *b = same_uniform(e, &n[i]);
    double t0 = clock_now(), t1 = t0;
    int rc = 0;
    if (!b) {
        if ((rc = fill_node(e, s, &n[i], raw))) return rc;
        t1 = clock_now();
        e->t.fill += t1 - t0;
        key[i] = XXH3_64bits(raw, rb);
        b = find_seen(e, s, key[i], raw, &rc);
        if (rc) return rc;
        if (b && n[i].uniform) keep_uniform(e, n[i].value, (size_t)(b - e->seen));
    }
    kind[i] = BATCH_NEW;
    if (b) {
        bt->rec[i] = b->rec;
        bt->same[i] = b->tag;
        kind[i] = BATCH_SEEN;
    }
    for (size_t j = 0; j < i && kind[i] == BATCH_NEW; j++)
        if (kind[j] == BATCH_NEW && key[j] == key[i] &&
            !memcmp(e->raw + j * rb, raw, rb))
            kind[i] = (int)j;
    e->t.hash += clock_now() - t1;
    return 0;
}

/* The file's hash of each new brick of the batch (SFHS four at a time). */
static void batch_hash(vod_encoder *e, const int *kind, size_t count,
                       vod_encoded *rec)
{
    size_t rb = e->L.raw_bytes, idx[VOD_ENCODE_BATCH], m = 0;
    for (size_t i = 0; i < count; i++)
        if (kind[i] == BATCH_NEW) idx[m++] = i;
    if (e->p.hash != VOD_HASH_SFHS || m < 2) {
        for (size_t k = 0; k < m; k++)
            rec[idx[k]].hash = vod_hash(e->p.hash, e->raw + idx[k] * rb, rb);
        return;
    }
    const void *d[4];
    uint32_t h[4];
    for (size_t k = 0; k < 4; k++) d[k] = e->raw + idx[k < m ? k : 0] * rb;
    vod_hash_sfhs4(d, rb, h);
    for (size_t k = 0; k < m; k++) rec[idx[k]].hash = h[k];
}

/* Brick i of b as a batch of its own. */
static vod_brick_batch batch_one(const vod_brick_batch *b, size_t i)
{
    return (vod_brick_batch){.n = b->n + i, .tag = b->tag + i, .count = 1,
                             .out = b->out + i, .cap = b->cap, .rec = b->rec + i,
                             .same = b->same + i};
}

int vod_encoder_put_batch(vod_encoder *e, const vod_source *s, const vod_brick_batch *b)
{
    const vod_node *n = b->n;
    const uint64_t *tag = b->tag;
    size_t count = b->count;
    vod_encoded *rec = b->rec;
    uint64_t *same = b->same;
    batch bt = {.rec = rec, .same = same};
    const int *kind = bt.kind;
    size_t rb = e->L.raw_bytes;
    if (count > VOD_ENCODE_BATCH) return -EINVAL;
    if (count > e->batch) { /* large bricks: one at a time */
        for (size_t i = 0; i < count; i++) {
            vod_brick_batch one = batch_one(b, i);
            int rc = vod_encoder_put_batch(e, s, &one);
            if (rc) return rc;
        }
        return 0;
    }
    for (size_t i = 0; i < count; i++) {
        int rc = batch_find(e, s, n, i, &bt);
        if (rc) return rc;
    }
    double t0 = clock_now();
    batch_hash(e, kind, count, rec);
    e->t.hash += clock_now() - t0;
    for (size_t i = 0; i < count; i++) {
        if (kind[i] == BATCH_SEEN) continue;
        if (kind[i] >= 0) {
            rec[i] = rec[kind[i]];
            same[i] = tag[kind[i]];
            continue;
        }
        t0 = clock_now();
        int rc = compress_brick(e, e->raw + i * rb, b->out[i], b->cap, &rec[i].size);
        e->t.compress += clock_now() - t0;
        if (rc) return rc;
        same[i] = tag[i];
        remember(e, bt.key[i], e->raw + i * rb, &n[i], &rec[i], tag[i]);
    }
    return 0;
}

int vod_encoder_put(vod_encoder *e, const vod_source *s, const vod_node *n,
                    uint64_t tag, const vod_brick_out *o, uint64_t *same)
{
    vod_brick_batch b = {.n = n, .tag = &tag, .count = 1, .out = &o->out, .cap = o->cap,
                         .rec = o->rec, .same = same};
    return vod_encoder_put_batch(e, s, &b);
}

/* vod_encode's encoder, one per thread, made again when the layout or the
 * encoding changes. */
static _Thread_local vod_encoder *tl_enc;

void vod_encode_cleanup(void)
{
    vod_encoder_free(tl_enc);
    tl_enc = NULL;
}

static bool encoder_fits(const vod_encoder *e, const vod_layout *L,
                         const vod_params *p)
{
    return e && e->L.brick == L->brick && e->L.voxel_bits == L->voxel_bits &&
           e->L.height == L->height && e->L.padded == L->padded &&
           e->p.comp == p->comp && e->p.hash == p->hash &&
           (p->comp != VOD_COMP_ZLIB || e->p.zlib_level == p->zlib_level);
}

int vod_encode(const vod_source *s, const vod_layout *L, const vod_params *p,
               const vod_node *n, uint8_t *scratch, const vod_brick_out *o)
{
    if (!encoder_fits(tl_enc, L, p)) {
        vod_encode_cleanup();
        int rc = vod_encoder_new(L, p, &tl_enc);
        if (rc) return rc;
    }
    int rc = fill_node(tl_enc, s, n, scratch);
    if (rc) return rc;
    o->rec->hash = vod_hash(p->hash, scratch, L->raw_bytes);
    return compress_brick(tl_enc, scratch, o->out, o->cap, &o->rec->size);
}

/* ---- all three phases ---- */

/* What encode_all encodes with: the encoder, the source, the nodes, a
 * batch's room (bound bytes a brick), and where the records, their
 * offsets and their bytes go. */
typedef struct {
    vod_encoder *e;
    const vod_source *s;
    const vod_node *nodes;
    uint8_t *tmp;
    size_t bound;
    vod_encoded *recs;
    size_t *off;
    vod_membuf *b;
} encode_job;

/* Nodes i..i+count-1 of encode_all, encoded together into j->tmp and
 * appended to j->b. */
static int encode_some(const encode_job *j, size_t i, size_t count)
{
    uint8_t *out[VOD_ENCODE_BATCH];
    uint64_t tag[VOD_ENCODE_BATCH], same[VOD_ENCODE_BATCH];
    for (size_t k = 0; k < count; k++) {
        out[k] = j->tmp + k * j->bound;
        tag[k] = i + k;
    }
    vod_brick_batch bb = {.n = &j->nodes[i], .tag = tag, .count = count, .out = out,
                          .cap = j->bound, .rec = &j->recs[i], .same = same};
    int rc = vod_encoder_put_batch(j->e, j->s, &bb);
    for (size_t k = 0; k < count && !rc; k++) {
        if (same[k] != i + k) {
            j->off[i + k] = j->off[same[k]];
            continue;
        }
        j->off[i + k] = j->b->n;
        rc = vod_mem_write(j->b, out[k], j->recs[i + k].size);
    }
    return rc;
}

/* Phase 2 for the n nodes of j (its source, nodes, records, offsets and
 * buffer set; its encoder and room made here), serially, into one buffer
 * (offsets in off; a duplicate the encoder found shares its first's); its
 * times into t. */
static int encode_all(encode_job *j, const vod_layout *L, const vod_params *p, size_t n,
                      vod_times *t)
{
    j->bound = vod_encode_bound(L, p);
    int rc = vod_encoder_new(L, p, &j->e);
    if (rc) return rc;
    j->tmp = malloc(VOD_ENCODE_BATCH * j->bound);
    rc = j->tmp ? 0 : -ENOMEM;
    for (size_t i = 0; i < n && !rc; i += VOD_ENCODE_BATCH) {
        size_t count = n - i < VOD_ENCODE_BATCH ? n - i : VOD_ENCODE_BATCH;
        rc = encode_some(j, i, count);
    }
    vod_times et;
    vod_encoder_times(j->e, &et);
    vod_times_add(t, &et);
    vod_encoder_free(j->e);
    free(j->tmp);
    return rc;
}

/* Phases 2 and 3 of a (its layout, parameters, sink, figures and message
 * set; the bricks filled in here); t_prepare the seconds phase 1 took. */
static int write_planned(const vod_source *s, vod_assembly *a, double t_prepare)
{
    const vod_layout *L = a->L;
    double t0 = clock_now();
    size_t n = vod_collect(s, L, NULL, 0);
    vod_node *nodes = malloc((n + 1) * sizeof *nodes);
    vod_encoded *recs = malloc((n + 1) * sizeof *recs);
    size_t *off = malloc((n + 1) * sizeof *off);
    const uint8_t **data = malloc((n + 1) * sizeof *data);
    vod_membuf b = {0};
    vod_times t = {0};
    int rc = nodes && recs && off && data ? 0 : -ENOMEM;
    if (!rc) {
        vod_collect(s, L, nodes, n);
        t.fill = clock_now() - t0 + t_prepare;
        encode_job j = {.s = s, .nodes = nodes, .recs = recs, .off = off, .b = &b};
        rc = encode_all(&j, L, a->p, n, &t);
    }
    if (!rc) {
        for (size_t i = 0; i < n; i++) data[i] = b.p + off[i];
        a->n = n;
        a->nodes = nodes;
        a->recs = recs;
        a->data = data;
        rc = vod_assemble(a);
    }
    if (!rc && a->st) vod_times_add(&a->st->t, &t);
    free(nodes);
    free(recs);
    free(off);
    free(data);
    free(b.p);
    return rc;
}

/* Phases 1 (after the checks) to 3 of a, as write_planned. */
static int write_checked(vod_source *s, vod_assembly *a)
{
    err_info *err = a->err;
    double t0 = clock_now();
    int rc = vod_prepare(s, a->L, a->p->channel, err);
    if (rc) return rc;
    err_clear(err);
    rc = write_planned(s, a, clock_now() - t0);
    /* vod_assemble's own failures are said; the sink's and the encoder's
     * are not yet */
    if (rc && (!err || !err->msg[0]))
        return err_set(err, rc, "cannot write the VOD file: %s", strerror(-rc));
    return rc;
}

int vod_write(vod_source *s, const vod_params *p, vod_sink *sink,
              vod_stats *st, err_info *err)
{
    vod_layout L;
    int rc = vod_layout_make(p, s->depth, &L, err);
    if (!rc) rc = vod_check_source(s, p, err);
    vod_assembly a = {.L = &L, .p = p, .sink = sink, .st = st, .err = err};
    return rc ? rc : write_checked(s, &a);
}

int vod_write_octree(octree *t, const vod_params *p, vod_sink *sink,
                     vod_stats *st, err_info *err)
{
    vod_source s = vod_octree_source(t);
    vod_layout L;
    int rc = vod_layout_make(p, t->depth, &L, err);
    if (!rc) rc = vod_check_source(&s, p, err);
    if (rc) return rc;
    uint32_t *own = NULL;
    if (!t->agg) {
        own = t->agg = malloc((size_t)t->used * sizeof *t->agg);
        if (!own)
            return err_set(err, -ENOMEM, "out of memory for %u cells", t->used);
    }
    vod_assembly a = {.L = &L, .p = p, .sink = sink, .st = st, .err = err};
    rc = write_checked(&s, &a);
    if (own) {
        free(own);
        t->agg = NULL;
    }
    return rc;
}

void vod_times_add(vod_times *to, const vod_times *t)
{
    to->fill += t->fill;
    to->hash += t->hash;
    to->compress += t->compress;
    to->assemble += t->assemble;
    to->write += t->write;
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
