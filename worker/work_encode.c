/* The encode kind's worker side: the mip levels of subtrees of the last
 * job's octree, then its VOD bricks encoded into the shared brick area.  Workers claim nodes in chunks from
 * the block's counter, so they share the work whatever its shape.  Each
 * worker's encoder finds the duplicates among the bricks it encodes before
 * compressing them: a duplicate's record points at its first's bytes. */
#include <errno.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "clock.h"
#include "vod_volume.h"
#include "work.h"

#define ENCODE_CHUNK 8u /* brick nodes claimed at a time */

typedef struct {
    uint8_t *out; /* VOD_ENCODE_BATCH bricks' encodings, bound bytes each */
    size_t bound;
    worker_chunk area; /* this worker's chunk of the brick area */
} encode_state;

static void encode_free(void *state)
{
    encode_state *st = state;
    if (!st) return;
    free(st->out);
    free(st);
}

/* Room for a batch of bricks' encodings, kept across jobs. */
static int encode_begin(worker_ctx *w, void **state)
{
    encode_state *st = *state;
    if (!st && !(st = *state = calloc(1, sizeof *st))) return -ENOMEM;
    const encode_block *b = shm_at(w->base, w->h->job_off);
    st->area = (worker_chunk){0, 0}; /* a new job's area */
    size_t want = vod_encode_bound(&b->L, &b->p);
    if (st->bound >= want) return 0;
    uint8_t *n = realloc(st->out, VOD_ENCODE_BATCH * want);
    if (!n) return -ENOMEM;
    st->out = n;
    st->bound = want;
    return 0;
}

static void encode_fail(encode_block *b, int rc)
{
    int zero = 0;
    /* relaxed: the master reads it after acquiring done_seq */
    atomic_compare_exchange_strong_explicit(&b->error, &zero, rc,
                                            memory_order_relaxed,
                                            memory_order_relaxed);
}

/* Node i, encoded into out (its record in rec, same: the tag of its
 * first), into the shared brick area.  A duplicate of a brick this worker
 * stored takes its offset; one whose first did not fit stays unrecorded
 * like it (the master encodes both). */
static void store_one(worker_ctx *w, encode_state *st, encode_block *b, uint64_t i,
                      const uint8_t *out, const vod_encoded *rec, uint64_t same)
{
    vod_encoded *recs = shm_at(w->base, b->recs_off);
    uint64_t *offs = shm_at(w->base, b->offs_off);
    if (same != i) {
        if (same < b->n && offs[same] < b->brick_cap) {
            recs[i] = *rec;
            offs[i] = offs[same];
        }
        return;
    }
    uint64_t off = worker_chunk_take(w, &st->area, &b->bump, b->brick_off, b->brick_cap, rec->size);
    /* Full: leave the node unrecorded, the master encodes it itself. */
    if (off == UINT64_MAX) return;
    memcpy((uint8_t *)shm_at(w->base, b->brick_off) + off, out, rec->size);
    recs[i] = *rec;
    offs[i] = off;
}

/* What a worker encodes the block's bricks with: its room, the block,
 * the source and its encoder. */
typedef struct {
    worker_ctx *w;
    encode_state *st;
    encode_block *b;
    const vod_source *src;
    vod_encoder *enc;
} encoder_run;

/* Nodes i0..i0+count-1 (count <= VOD_ENCODE_BATCH), encoded together. */
static int encode_batch(const encoder_run *r, uint64_t i0, size_t count)
{
    const vod_node *nodes = shm_at(r->w->base, r->b->nodes_off);
    uint8_t *out[VOD_ENCODE_BATCH];
    uint64_t tag[VOD_ENCODE_BATCH], same[VOD_ENCODE_BATCH];
    vod_encoded rec[VOD_ENCODE_BATCH];
    for (size_t k = 0; k < count; k++) {
        out[k] = r->st->out + k * r->st->bound;
        tag[k] = i0 + k;
    }
    vod_brick_batch bb = {.n = &nodes[i0], .tag = tag, .count = count, .out = out,
                          .cap = r->st->bound, .rec = rec, .same = same};
    int rc = vod_encoder_put_batch(r->enc, r->src, &bb);
    if (rc) return rc;
    for (size_t k = 0; k < count; k++)
        store_one(r->w, r->st, r->b, i0 + k, out[k], &rec[k], same[k]);
    return 0;
}

static int encode_nodes(const encoder_run *r)
{
    worker_ctx *w = r->w;
    encode_block *b = r->b;
    for (;;) {
        /* relaxed: a counter that hands out disjoint chunks */
        if (worker_aborted(w)) return -ECANCELED; /* the job was cancelled */
        uint64_t i0 = atomic_fetch_add_explicit(&b->next, ENCODE_CHUNK,
                                                memory_order_relaxed);
        if (i0 >= b->n) return 0;
        uint64_t end = i0 + ENCODE_CHUNK < b->n ? i0 + ENCODE_CHUNK : b->n;
        for (uint64_t i = i0; i < end; i += VOD_ENCODE_BATCH) {
            /* relaxed: stop early once anybody failed */
            if (atomic_load_explicit(&b->error, memory_order_relaxed)) return 0;
            worker_tick(w);
            size_t count = end - i < VOD_ENCODE_BATCH ? end - i : VOD_ENCODE_BATCH;
            int rc = encode_batch(r, i, count);
            if (rc) return rc;
        }
    }
}

static void add_ns(atomic_ullong *to, double seconds)
{
    /* relaxed: read by the master after every done_seq acquire */
    atomic_fetch_add_explicit(to, (unsigned long long)(seconds * 1e9),
                              memory_order_relaxed);
}

/* The mip levels of the subtrees this worker claims; each one's done byte
 * set when it is complete. */
static int aggregate_run(worker_ctx *w, encode_block *b, octree *tree)
{
    const uint32_t *roots = shm_at(w->base, b->roots_off);
    uint8_t *done = shm_at(w->base, b->roots_done_off);
    double t0 = clock_now();
    for (;;) {
        if (worker_aborted(w)) return -ECANCELED;
        /* relaxed: a counter that hands out disjoint subtrees */
        uint64_t i = atomic_fetch_add_explicit(&b->agg_next, 1, memory_order_relaxed);
        if (i >= b->nroots) break;
        if (roots[i] == 0 || roots[i] >= b->cells_used) return -EINVAL;
        worker_tick(w);
        vod_aggregate_subtree(tree, roots[i], b->root_height, b->p.channel);
        done[i] = 1;
    }
    add_ns(&b->ns_fill, clock_now() - t0);
    return 0;
}

/* The source the block names: the octree (its view in *tree) or the
 * volume the master prepared. */
static int block_source(worker_ctx *w, const encode_block *b, octree *tree,
                        vod_source *src)
{
    if (b->source == ENCODE_VOLUME) {
        vod_volume *v = vod_volume_view(shm_at(w->base, b->volume_off));
        if (!v) return -EINVAL;
        *src = vod_volume_source(v);
        return 0;
    }
    octree_view(tree, shm_at(w->base, b->cells_off), b->cells_used, b->depth);
    tree->agg = shm_at(w->base, b->agg_off);
    *src = vod_octree_source(tree);
    return 0;
}

static int encode_run(worker_ctx *w, void *state, const shm_task *t)
{
    encode_block *b = shm_at(w->base, w->h->job_off);
    octree tree;
    vod_source src;
    int rc = block_source(w, b, &tree, &src);
    if (rc) return rc;
    if (t->op == ENCODE_AGGREGATE && b->source == ENCODE_OCTREE)
        return aggregate_run(w, b, &tree);
    if (t->op != ENCODE_BRICKS) return -EINVAL;
    vod_encoder *enc;
    rc = vod_encoder_new(&b->L, &b->p, &enc);
    if (!rc) {
        rc = encode_nodes(&(encoder_run){w, state, b, &src, enc});
        vod_times tm;
        vod_encoder_times(enc, &tm);
        add_ns(&b->ns_fill, tm.fill);
        add_ns(&b->ns_hash, tm.hash);
        add_ns(&b->ns_compress, tm.compress);
        vod_encoder_free(enc);
    }
    if (rc && rc != -ECANCELED) encode_fail(b, rc);
    return rc;
}

const worker_kind worker_encode = {
    .name = "encode",
    .begin = encode_begin,
    .run = encode_run,
    .free = encode_free,
};
