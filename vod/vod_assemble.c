/* Phase 3 of the writer (vod.h: vod_assemble): the encoded bricks laid out
 * as a VOD file and streamed to the sink.
 *
 * The duplicates are removed first (IDs by first use), then the layout is
 * known: each unique brick's offset is a prefix sum of the sizes before
 * it.  Every byte of the file before the trailer is then a function of its
 * offset alone (the header, the octree table, the brick table, a brick's
 * size field or data), so the file is cut into chunks that threads render
 * and checksum independently (render_range), while the caller's thread
 * writes the chunks to the sink in order, rendering chunks ahead while
 * the next one is not ready.  The trailer's CRC-32 is the chunks' CRCs
 * combined (crc32_combine) and the trailer's own bytes after them.  The
 * sink sees the same writes in the same order whatever the thread count,
 * so the bytes are those of one thread. */
#include "vod.h"

#include <errno.h>
#include <pthread.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <zlib.h>

#include "clock.h"
#include "err.h"
#include "par.h"
#include "voxel.h"

#define TRAILER_FIXED 40u     /* trailer bytes besides the metadata */
#define CHUNK_BYTES (1u << 20) /* what one thread renders at a time */
#define ASSEMBLE_THREADS 16u  /* more only wait on the sink and the memory */
#define NO_CHUNK UINT64_MAX

/* The file's layout: where each part starts, the unique bricks' offsets. */
typedef struct {
    const vod_node *nodes;
    const vod_encoded *recs;
    const uint8_t *const *data;
    const uint32_t *ids, *first;
    size_t n;
    uint32_t u;
    uint64_t count_at;  /* the brick count, after the octree table */
    uint64_t btable_at; /* the brick table */
    uint64_t *boff;     /* u + 1: brick j's size field; boff[u], the trailer */
    uint8_t header[VOD_HEADER_BYTES];
} file_plan;

static uint32_t f32_bits(float f)
{
    uint32_t u;
    memcpy(&u, &f, sizeof u);
    return u;
}

static void make_header(uint8_t *h, const vod_layout *L, const vod_params *p)
{
    uint32_t flags = VOD_FLAG_TRAILER;
    if (p->comp != VOD_COMP_NONE) flags |= VOD_FLAG_COMPRESSED;
    if (p->channel == VOXEL_CH_DISTANCE) flags |= VOD_FLAG_FLOAT;
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
}

/* The part of [at, at + len) (bytes src) inside [a, b), into out (which
 * holds [a, b)). */
static void put_clipped(uint8_t *out, uint64_t a, uint64_t b, uint64_t at,
                        const void *src, uint64_t len)
{
    uint64_t lo = at > a ? at : a, hi = at + len < b ? at + len : b;
    if (lo < hi) memcpy(out + (lo - a), (const uint8_t *)src + (lo - at), hi - lo);
}

static void put32_clipped(uint8_t *out, uint64_t a, uint64_t b, uint64_t at,
                          uint32_t v)
{
    uint8_t w[4];
    vod_put32(w, v);
    put_clipped(out, a, b, at, w, 4);
}

/* The first node whose table entry ends after byte a of the file. */
static size_t first_node(const file_plan *f, uint64_t a)
{
    size_t lo = 0, hi = f->n;
    while (lo < hi) {
        size_t mid = lo + (hi - lo) / 2;
        if (VOD_HEADER_BYTES + 4 * f->nodes[mid].preorder + 4 <= a) lo = mid + 1;
        else hi = mid;
    }
    return lo;
}

/* The first unique brick whose bytes end after byte a. */
static uint32_t first_brick(const file_plan *f, uint64_t a)
{
    uint32_t lo = 0, hi = f->u;
    while (lo < hi) {
        uint32_t mid = lo + (hi - lo) / 2;
        if (f->boff[mid + 1] <= a) lo = mid + 1;
        else hi = mid;
    }
    return lo;
}

/* Bytes [a, b) of the file (b at most the trailer's start) into out:
 * zeros, then whatever of each part falls inside. */
static void render_range(const file_plan *f, uint64_t a, uint64_t b, uint8_t *out)
{
    memset(out, 0, b - a); /* the octree table's empty nodes */
    put_clipped(out, a, b, 0, f->header, VOD_HEADER_BYTES);
    for (size_t i = first_node(f, a); i < f->n; i++) {
        uint64_t at = VOD_HEADER_BYTES + 4 * f->nodes[i].preorder;
        if (at >= b) break;
        put32_clipped(out, a, b, at, f->ids[i]);
    }
    put32_clipped(out, a, b, f->count_at, f->u);
    uint64_t j0 = a > f->btable_at ? (a - f->btable_at) / 12 : 0;
    for (uint64_t j = j0; j < f->u && f->btable_at + 12 * j < b; j++) {
        uint8_t e[12];
        vod_put32(e, (uint32_t)j + 1);
        vod_put32(e + 4, (uint32_t)f->boff[j]);
        vod_put32(e + 8, f->recs[f->first[j]].hash);
        put_clipped(out, a, b, f->btable_at + 12 * j, e, 12);
    }
    for (uint32_t j = first_brick(f, a); j < f->u && f->boff[j] < b; j++) {
        const vod_encoded *r = &f->recs[f->first[j]];
        put32_clipped(out, a, b, f->boff[j], r->size);
        put_clipped(out, a, b, f->boff[j] + 4, f->data[f->first[j]], r->size);
    }
}

/* The chunks in flight: renderers claim them in order (next), the writer
 * writes them in order (written); a chunk's slot in the ring is free once
 * the chunk R before it is written.  mu guards every field below it. */
typedef struct {
    const file_plan *f;
    vod_sink *sink;
    uint64_t body, nchunks;
    unsigned slots;
    uint8_t *ring;
    uint64_t *in_slot; /* the chunk rendered in each slot, or NO_CHUNK */
    uint32_t *crc;     /* its CRC-32 */
    pthread_mutex_t mu;
    pthread_cond_t cv;
    uint64_t next, written;
    int err;
    uint32_t file_crc; /* of every chunk written, in order */
    double t_write;    /* seconds in the sink's write */
} stream;

static uint64_t chunk_len(const stream *s, uint64_t c)
{
    uint64_t a = c * CHUNK_BYTES;
    return s->body - a < CHUNK_BYTES ? s->body - a : CHUNK_BYTES;
}

/* Renders chunk c into its slot and publishes it (mu not held). */
static void render_chunk(stream *s, uint64_t c)
{
    uint64_t a = c * CHUNK_BYTES, len = chunk_len(s, c);
    uint8_t *out = s->ring + (size_t)(c % s->slots) * CHUNK_BYTES;
    render_range(s->f, a, a + len, out);
    uint32_t crc = (uint32_t)crc32(0, out, (uInt)len);
    pthread_mutex_lock(&s->mu);
    s->crc[c % s->slots] = crc;
    s->in_slot[c % s->slots] = c;
    pthread_cond_broadcast(&s->cv);
    pthread_mutex_unlock(&s->mu);
}

/* A renderer: claims the next chunk while its slot is free. */
static void renderer(stream *s)
{
    for (;;) {
        pthread_mutex_lock(&s->mu);
        while (!s->err && s->next < s->nchunks && s->next >= s->written + s->slots)
            pthread_cond_wait(&s->cv, &s->mu);
        if (s->err || s->next >= s->nchunks) {
            pthread_mutex_unlock(&s->mu);
            return;
        }
        uint64_t c = s->next++;
        pthread_mutex_unlock(&s->mu);
        render_chunk(s, c);
    }
}

/* Writes chunk c (rendered) to the sink, its CRC combined (mu held on
 * entry and on return, not during the write). */
static void write_chunk(stream *s, uint64_t c)
{
    uint32_t crc = s->crc[c % s->slots];
    pthread_mutex_unlock(&s->mu);
    uint64_t len = chunk_len(s, c);
    double t0 = clock_now();
    int rc = s->sink->write(s->sink->ud, s->ring + (size_t)(c % s->slots) * CHUNK_BYTES,
                            (size_t)len);
    s->t_write += clock_now() - t0;
    s->file_crc = (uint32_t)crc32_combine(s->file_crc, crc, (z_off_t)len);
    pthread_mutex_lock(&s->mu);
    if (rc < 0) s->err = rc;
    s->in_slot[c % s->slots] = NO_CHUNK;
    s->written = c + 1;
    pthread_cond_broadcast(&s->cv);
}

/* The writer: every chunk in order to the sink; while the next one is not
 * ready it renders one ahead, as a renderer does, so that every thread
 * renders (it sleeps only when every free slot is claimed). */
static void writer(stream *s)
{
    pthread_mutex_lock(&s->mu);
    while (s->written < s->nchunks && !s->err) {
        uint64_t c = s->written;
        if (s->in_slot[c % s->slots] == c) {
            write_chunk(s, c);
        } else if (s->next < s->nchunks && s->next < s->written + s->slots) {
            uint64_t k = s->next++;
            pthread_mutex_unlock(&s->mu);
            render_chunk(s, k);
            pthread_mutex_lock(&s->mu);
        } else {
            pthread_cond_wait(&s->cv, &s->mu);
        }
    }
    pthread_mutex_unlock(&s->mu);
}

static void stream_part(void *ud, unsigned k, unsigned n)
{
    (void)n;
    if (k == 0) writer(ud);
    else renderer(ud);
}

/* The body (everything before the trailer) to the sink; its CRC in *crc. */
static int stream_body(const file_plan *f, uint64_t body, vod_sink *sink,
                       uint32_t *crc, double *t_write)
{
    stream s = {.f = f, .sink = sink, .body = body,
                .nchunks = (body + CHUNK_BYTES - 1) / CHUNK_BYTES};
    unsigned threads = par_cpus();
    if (threads > ASSEMBLE_THREADS) threads = ASSEMBLE_THREADS;
    if (threads > s.nchunks) threads = s.nchunks ? (unsigned)s.nchunks : 1;
    s.slots = 2 * threads;
    s.ring = malloc((size_t)s.slots * CHUNK_BYTES);
    s.in_slot = malloc(s.slots * sizeof *s.in_slot);
    s.crc = malloc(s.slots * sizeof *s.crc);
    if (!s.ring || !s.in_slot || !s.crc) s.err = -ENOMEM;
    for (unsigned i = 0; !s.err && i < s.slots; i++) s.in_slot[i] = NO_CHUNK;
    if (!s.err) {
        pthread_mutex_init(&s.mu, NULL);
        pthread_cond_init(&s.cv, NULL);
        par_run(threads, stream_part, &s);
        pthread_cond_destroy(&s.cv);
        pthread_mutex_destroy(&s.mu);
    }
    free(s.ring);
    free(s.in_slot);
    free(s.crc);
    *crc = s.file_crc;
    *t_write = s.t_write;
    return s.err;
}

/* Section 7, at offset at; the CRC covers every byte before its own field
 * (crc: the body's).  Written in one piece. */
static int write_trailer(const vod_params *p, uint64_t at, size_t meta, vod_sink *sink,
                         uint32_t *crc, double *t_write)
{
    size_t len = TRAILER_FIXED + meta;
    uint8_t *t = malloc(len);
    if (!t) return -ENOMEM;
    memcpy(t, "VODX", 4);
    vod_put32(t + 4, (uint32_t)len);
    for (int a = 0; a < 3; a++) vod_put32(t + 8 + 4 * a, f32_bits(p->origin[a]));
    vod_put32(t + 20, (uint32_t)p->channel);
    vod_put32(t + 24, (uint32_t)meta);
    if (meta) memcpy(t + 28, p->metadata, meta);
    vod_put32(t + 28 + meta, (uint32_t)at);
    memcpy(t + 32 + meta, "XDOV", 4);
    *crc = (uint32_t)crc32(*crc, t, (uInt)(len - 4));
    vod_put32(t + 36 + meta, *crc);
    double t0 = clock_now();
    int rc = sink->write(sink->ud, t, len);
    *t_write += clock_now() - t0;
    free(t);
    return rc < 0 ? rc : 0;
}

/* Duplicates: every brick pointed at the first brick with the same bytes
 * (first_of[i] = j <= i), then IDs 1..u by first use.  Candidates come
 * from the hash; a match is confirmed by comparing the encoded bytes.
 * That is the same as comparing the raw bricks: every brick of a file is
 * encoded by the same deterministic function of its raw bytes (same
 * algorithm, same level), so equal raw bricks give equal encodings, and
 * decoding is a function, so equal encodings come from equal raw bricks.
 * Equal hashes alone never merge.  Duplicates an encoder already found
 * (vod_encoder_put) point at the same bytes: no comparison then.
 *
 * The search runs on several threads (issue 24: it was a serial span of
 * 0.1-0.25 s after the bricks on a loaded machine): the hashes are cut
 * into parts by a mix of their bits, each part searched by one thread in
 * a table of its own, in the bricks' order.  Equal bytes have equal
 * hashes, so a brick's duplicates are all in its part, and the first of
 * them is found whatever the other parts do: the IDs are those of one
 * thread. */
#define DEDUP_MIN_PER_THREAD 8192u /* fewer bricks a thread: not worth one */

typedef struct {
    size_t n;
    const vod_encoded *recs;
    const uint8_t *const *data;
    uint32_t *first_of;
    atomic_int err; /* -ENOMEM from any part (relaxed: read after par_run's
                       join, which orders it) */
} dedup_job;

static unsigned dedup_part(uint32_t h, unsigned n)
{
    return (unsigned)(((uint64_t)(uint32_t)(h * 2654435761u) * n) >> 32);
}

static int same_brick(const dedup_job *d, size_t k, size_t i)
{
    const vod_encoded *r = d->recs;
    return r[k].hash == r[i].hash && r[k].size == r[i].size &&
           (d->data[k] == d->data[i] ||
            memcmp(d->data[k], d->data[i], r[i].size) == 0);
}

/* Part k of n: its bricks, in order, into a table of first indices + 1. */
static void dedup_part_run(void *ud, unsigned k, unsigned n)
{
    dedup_job *d = ud;
    size_t mine = 0, cap = 16;
    for (size_t i = 0; i < d->n; i++) mine += dedup_part(d->recs[i].hash, n) == k;
    while (cap < 2 * mine) cap *= 2;
    uint32_t *slot = calloc(cap, sizeof *slot);
    if (!slot) {
        atomic_store_explicit(&d->err, -ENOMEM, memory_order_relaxed);
        return;
    }
    for (size_t i = 0; i < d->n; i++) {
        uint32_t h = d->recs[i].hash;
        if (dedup_part(h, n) != k) continue;
        for (size_t j = (h ^ h >> 15) & (cap - 1);; j = (j + 1) & (cap - 1)) {
            if (!slot[j]) {
                slot[j] = (uint32_t)i + 1;
                d->first_of[i] = (uint32_t)i;
                break;
            }
            if (same_brick(d, slot[j] - 1, i)) {
                d->first_of[i] = slot[j] - 1;
                break;
            }
        }
    }
    free(slot);
}

/* ids[i] in 1..u, first[id - 1] the brick that first used it. */
static int dedup(size_t n, const vod_encoded *recs, const uint8_t *const *data,
                 uint32_t *ids, uint32_t *first, uint32_t *unique)
{
    dedup_job d = {.n = n, .recs = recs, .data = data, .first_of = first};
    atomic_init(&d.err, 0);
    unsigned threads = par_cpus();
    if (threads > ASSEMBLE_THREADS) threads = ASSEMBLE_THREADS;
    if (threads > n / DEDUP_MIN_PER_THREAD) threads = (unsigned)(n / DEDUP_MIN_PER_THREAD);
    par_run(threads ? threads : 1, dedup_part_run, &d);
    int rc = atomic_load_explicit(&d.err, memory_order_relaxed);
    if (rc) return rc;
    /* first[] held first_of[]; ids[] now, then first[] over it: the u-th
     * new brick is at i >= u - 1, so first[u - 1] is no longer read. */
    uint32_t u = 0;
    for (size_t i = 0; i < n; i++) {
        uint32_t j = first[i];
        ids[i] = j == i ? ++u : ids[j];
        if (j == i) first[u - 1] = (uint32_t)i;
    }
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

/* The parts' offsets; the bricks' as prefix sums of their sizes. */
static void plan_layout(file_plan *f, const vod_layout *L)
{
    f->count_at = VOD_HEADER_BYTES + 4 * L->nodes;
    f->btable_at = f->count_at + 4;
    f->boff[0] = f->btable_at + 12ull * f->u;
    for (uint32_t j = 0; j < f->u; j++)
        f->boff[j + 1] = f->boff[j] + 4 + (uint64_t)f->recs[f->first[j]].size;
}

static void fill_stats(vod_stats *st, const vod_layout *L, const file_plan *f,
                       uint64_t file_bytes, uint32_t crc)
{
    uint64_t side = L->padded;
    memset(st, 0, sizeof *st);
    st->file_bytes = file_bytes;
    st->raw_bytes = side * side * side * L->voxel_bits / 8;
    st->nodes = L->nodes;
    st->nonempty_nodes = f->n;
    st->bricks = f->u;
    st->brick_raw_bytes = (uint64_t)f->u * L->raw_bytes;
    st->brick_data_bytes = f->boff[f->u] - f->boff[0] - 4ull * f->u;
    st->crc32 = crc;
}

/* The 4 GiB limit, with what to ask for instead. */
static int too_big(err_info *err, const vod_layout *L, const vod_params *p,
                   uint32_t unique)
{
    return err_set(err, -EFBIG,
                "the VOD file would pass 4 GiB, the limit of the format's 32-bit "
                "offsets (%u unique bricks of %u^3 voxels); ask for %s",
                unique, L->brick,
                p->comp == VOD_COMP_NONE ? "compression (zlib or runl), a larger brick "
                                           "or a lower res"
                                         : "a larger brick or a lower res");
}

/* The file from its plan: the body streamed, then the trailer. */
static int write_file(const vod_layout *L, const vod_params *p, file_plan *f,
                      vod_sink *sink, vod_stats *st, double t0)
{
    size_t meta = p->metadata ? strlen(p->metadata) : 0;
    uint64_t body = f->boff[f->u];
    uint32_t crc;
    double t_write = 0;
    make_header(f->header, L, p);
    int rc = stream_body(f, body, sink, &crc, &t_write);
    if (!rc) rc = write_trailer(p, body, meta, sink, &crc, &t_write);
    if (!rc && st) {
        fill_stats(st, L, f, body + TRAILER_FIXED + meta, crc);
        st->t.write = t_write;
        st->t.assemble = clock_now() - t0 - t_write;
    }
    return rc;
}

int vod_assemble(const vod_assembly *a)
{
    const vod_layout *L = a->L;
    const vod_params *p = a->p;
    size_t n = a->n;
    err_info *err = a->err;
    err_clear(err);
    double t0 = clock_now();
    int rc = check_inputs(L, p, n, a->nodes, a->recs, a->data);
    if (rc)
        return err_set(err, rc, "bricks out of preorder or over their bound");
    uint32_t *ids = malloc((n + 1) * sizeof *ids);
    uint32_t *first = malloc((n + 1) * sizeof *first);
    file_plan f = {.nodes = a->nodes, .recs = a->recs, .data = a->data, .ids = ids,
                   .first = first, .n = n};
    rc = ids && first ? dedup(n, a->recs, a->data, ids, first, &f.u) : -ENOMEM;
    if (!rc && !(f.boff = malloc(((size_t)f.u + 1) * sizeof *f.boff))) rc = -ENOMEM;
    if (rc) {
        err_set(err, rc, "out of memory for %zu bricks", n);
    } else {
        plan_layout(&f, L);
        size_t meta = p->metadata ? strlen(p->metadata) : 0;
        if (f.boff[f.u] + TRAILER_FIXED + meta > UINT32_MAX)
            rc = too_big(err, L, p, f.u);
        else
            rc = write_file(L, p, &f, a->sink, a->st, t0);
    }
    free(f.boff);
    free(ids);
    free(first);
    return rc;
}

/* zlib's bound for a deflate stream whose parameters are not the defaults
 * (deflateBound's conservative case), plus the zlib wrapper: more than
 * libdeflate_zlib_compress needs (test_vod checks it), so compression
 * into a buffer of this size never fails for room. */
size_t vod_encode_bound(const vod_layout *L, const vod_params *p)
{
    size_t n = L->raw_bytes;
    if (p->comp == VOD_COMP_ZLIB)
        return n + ((n + 7) >> 3) + ((n + 63) >> 6) + 5 + 6 + 16;
    if (p->comp == VOD_COMP_RUNL) return vod_runl_bound(L->voxel_bits, n);
    return n;
}
