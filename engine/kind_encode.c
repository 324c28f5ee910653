/* The encode kind's master side: the last implicit job's octree written as
 * VOD, its mip levels and its bricks made by every worker in parallel in
 * the segment.  The block and its arrays are laid out behind the octree's
 * used cells: the aggregate (u32 per cell), the aggregate's subtree roots
 * and their done bytes, the brick nodes, their encoded records and
 * offsets, then the brick bytes.  Two phases: the workers aggregate the
 * subtrees below the cells AGG_SPLIT levels under the root while the
 * master waits, then (when the last of those tasks is done) the master
 * aggregates the cells above them and hands out the bricks.  A worker's
 * death or failure costs nothing but time: the subtrees and the bricks it
 * left undone are done here.
 * The stage times (vod_times) are the sum of the master's (planning,
 * what it encodes, assembling) and the workers'. */
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "clock.h"
#include "kind_encode.h"
#include "master.h"
#include "par.h"

typedef struct {
    const vod_params *p;
    vod_layout L;
    vod_sink *sink;
    vod_stats *st;
    engine_error *err;
    vod_times t;   /* the master's fill, hash and compress */
    int agg_left;  /* aggregate tasks not done yet */
    engine_deliver deliver; /* NULL: assemble the file into sink */
    void *deliver_ud;
    /* The plan of an octree, on a thread of its own while the workers
     * build the mip levels (setup_octree): the brick nodes listed at
     * nodes_off (up to plan_cap) and their offsets set to -1. */
    par_task plan;
    int planning;        /* started and not joined yet */
    engine *plan_e;
    uint64_t nodes_off, plan_cap, plan_n;
    double plan_s;
} encode_job;

/* The aggregate's subtrees: the cells AGG_SPLIT levels under the root,
 * up to 8^3 of them, or AGG_FINE levels (8^4) where those cells are still
 * the master's (engine.tree_top): the last subtrees are then smaller and
 * the workers end the phase together (issue 24: one worker alone for up
 * to 20 ms of a loaded machine at the sphere's 2048^3).  Not below the
 * master's cells: the master reads the roots' aggregates, and roots in
 * the workers' blocks lie one to a page, each page a fault of the
 * master's (union64 at 1024^3: 3580 roots, 0.11-0.14 s under load). */
#define AGG_SPLIT 3
#define AGG_FINE 4

/* The last job's result as a brick source. */
static vod_source result_source(engine *e)
{
    return e->result == RESULT_VOLUME ? vod_volume_source(e->volume)
                                      : vod_octree_source(&e->tree);
}

/* One task of op per live worker; how many in *pushed. */
static int push_all(engine *e, uint32_t op, int *pushed)
{
    shm_task t = {.kind = SHM_KIND_ENCODE, .op = op};
    int rc = 0;
    *pushed = 0;
    for (int i = 0; i < e->n && !rc; i++)
        if (e->ms[i].pid > 0 && !(rc = engine_sched_push(e, &t))) ++*pushed;
    return rc;
}

static int plan_join(engine *e, encode_job *ej);

/* The aggregate's second phase, here: the subtrees no worker finished,
 * the cells above them; then the bricks are handed out. */
static int aggregate_rest(engine *e, encode_job *ej)
{
    int rc = plan_join(e, ej);
    if (rc) return rc;
    encode_block *b = engine_sched_block(e);
    const uint32_t *roots = shm_at(e->seg.base, b->roots_off);
    const uint8_t *done = shm_at(e->seg.base, b->roots_done_off);
    double t0 = clock_now();
    for (uint64_t i = 0; i < b->nroots; i++)
        if (!done[i])
            vod_aggregate_subtree(&e->tree, roots[i], b->root_height, ej->p->channel);
    if (b->nroots) vod_aggregate_top(&e->tree, b->root_height, ej->p->channel);
    else vod_aggregate(&e->tree, ej->p->channel);
    ej->t.fill += clock_now() - t0;
    int pushed;
    return push_all(e, ENCODE_BRICKS, &pushed);
}

/* The block's fields; the counters start at 0 (relaxed: published to the
 * workers by the task_seq release). */
static void block_init(engine *e, encode_job *ej, encode_block *b)
{
    b->L = ej->L;
    b->p = *ej->p;
    b->p.metadata = NULL;
    b->cells_used = e->tree.used;
    b->depth = e->tree.depth;
    atomic_store_explicit(&b->next, 0, memory_order_relaxed);
    atomic_store_explicit(&b->agg_next, 0, memory_order_relaxed);
    atomic_store_explicit(&b->bump, 0, memory_order_relaxed);
    atomic_store_explicit(&b->error, 0, memory_order_relaxed);
    atomic_store_explicit(&b->ns_fill, 0, memory_order_relaxed);
    atomic_store_explicit(&b->ns_hash, 0, memory_order_relaxed);
    atomic_store_explicit(&b->ns_compress, 0, memory_order_relaxed);
}

static int no_room(engine *e)
{
    return engine_sched_fail(e, ENGINE_LIMIT, -ENOSPC,
                      "no room left in shared memory for the VOD bricks; "
                      "raise its size (now %zu MiB)", e->seg.bytes >> 20);
}

/* How many brick nodes fit at nodes_off: the nodes are the first array,
 * so when they do not all fit there, nothing after them does. */
static uint64_t nodes_cap(const engine *e, uint64_t nodes)
{
    uint64_t end = e->h->data_off + e->h->data_bytes;
    return nodes < end ? (end - nodes) / sizeof(vod_node) : 0;
}

/* Behind the n brick nodes at nodes: their records, offsets and the brick
 * area up to the end of the data area; every offset to -1 (not encoded).
 * The offsets are set by the caller (set_offsets). */
static int lay_out_rest(engine *e, encode_block *b, uint64_t nodes, uint64_t n)
{
    uint64_t end = e->h->data_off + e->h->data_bytes;
    b->recs_off = engine_sched_align64(nodes + n * sizeof(vod_node));
    b->offs_off = engine_sched_align64(b->recs_off + n * sizeof(vod_encoded));
    b->brick_off = engine_sched_align64(b->offs_off + n * sizeof(uint64_t));
    if (n > nodes_cap(e, nodes) || b->brick_off > end) return no_room(e);
    b->nodes_off = nodes;
    b->n = n;
    b->brick_cap = end - b->brick_off;
    return 0;
}

static void set_offsets(engine *e, uint64_t nodes, uint64_t n)
{
    uint64_t recs = engine_sched_align64(nodes + n * sizeof(vod_node));
    uint64_t offs = engine_sched_align64(recs + n * sizeof(vod_encoded));
    memset(shm_at(e->seg.base, offs), 0xff, n * sizeof(uint64_t));
}

/* The brick nodes straight into the segment at nodes, their offsets to -1
 * when there is room; how many in *n. */
static void plan_bricks(engine *e, const vod_layout *L, const vod_source *src,
                        uint64_t nodes, uint64_t *n)
{
    uint64_t cap = nodes_cap(e, nodes);
    *n = vod_collect(src, L, shm_at(e->seg.base, nodes), (size_t)cap);
    uint64_t end = e->h->data_off + e->h->data_bytes;
    uint64_t brick_off = engine_sched_align64(engine_sched_align64(engine_sched_align64(nodes + *n * sizeof(vod_node)) +
                                         *n * sizeof(vod_encoded)) +
                                 *n * sizeof(uint64_t));
    if (*n <= cap && brick_off <= end) set_offsets(e, nodes, *n);
}

static int lay_out_bricks(engine *e, encode_job *ej, encode_block *b,
                          const vod_source *src, uint64_t nodes)
{
    double t0 = clock_now();
    uint64_t n;
    plan_bricks(e, &ej->L, src, nodes, &n);
    ej->t.fill += clock_now() - t0;
    return lay_out_rest(e, b, nodes, n);
}

/* The plan's thread: the octree's brick nodes (the cells only: the mip
 * levels the workers build meanwhile are not read). */
static void *plan_run(void *arg)
{
    encode_job *ej = arg;
    double t0 = clock_now();
    vod_source src = vod_octree_source(&ej->plan_e->tree);
    plan_bricks(ej->plan_e, &ej->L, &src, ej->nodes_off, &ej->plan_n);
    ej->plan_s = clock_now() - t0;
    return NULL;
}

/* Waits for the plan and lays the bricks' arrays out behind its nodes. */
static int plan_join(engine *e, encode_job *ej)
{
    if (!ej->planning) return 0;
    par_join(&ej->plan);
    ej->planning = 0;
    ej->t.fill += ej->plan_s;
    return lay_out_rest(e, engine_sched_block(e), ej->nodes_off, ej->plan_n);
}

/* The octree: lay the block and its arrays out behind the used cells,
 * list the aggregate's subtrees, start the plan (the brick nodes) on a
 * thread of its own, and push one aggregate task per worker (none: the
 * master does it all and hands out the bricks once the plan is done). */
static int setup_octree(engine *e, encode_job *ej)
{
    uint64_t end = e->h->data_off + e->h->data_bytes;
    uint64_t cells_off = (uint64_t)((uint8_t *)e->tree.cells - e->seg.base);
    uint64_t boff = engine_sched_align64(cells_off + (uint64_t)e->tree.used * sizeof(octree_cell));
    uint64_t agg = engine_sched_align64(boff + sizeof(encode_block));
    uint64_t roots = engine_sched_align64(agg + (uint64_t)e->tree.used * sizeof(uint32_t));
    int hr = e->tree.depth - 1 - AGG_SPLIT, fine = e->tree.depth - 1 - AGG_FINE;
    if (e->tree_top >= 0 && fine >= e->tree_top) hr = fine;
    uint64_t nroots = hr >= 0 ? vod_aggregate_roots(&e->tree, hr, NULL, 0) : 0;
    uint64_t nodes = engine_sched_align64(roots + nroots * (sizeof(uint32_t) + 1));
    if (nodes > end) return no_room(e);
    encode_block *b = shm_at(e->seg.base, boff);
    e->tree.agg = shm_at(e->seg.base, agg);
    vod_aggregate_roots(&e->tree, hr, shm_at(e->seg.base, roots), nroots);
    memset(shm_at(e->seg.base, roots + nroots * sizeof(uint32_t)), 0, nroots);
    block_init(e, ej, b);
    b->source = ENCODE_OCTREE;
    b->cells_off = cells_off;
    b->agg_off = agg;
    b->roots_off = roots;
    b->roots_done_off = roots + nroots * sizeof(uint32_t);
    b->nroots = nroots;
    b->root_height = hr;
    b->n = 0; /* the bricks' fields: once the plan is joined */
    e->h->job_off = boff;
    e->h->job_bytes = sizeof *b;
    ej->plan_e = e;
    ej->nodes_off = nodes;
    ej->planning = 1;
    par_start(&ej->plan, plan_run, ej);
    int rc = nroots ? push_all(e, ENCODE_AGGREGATE, &ej->agg_left) : 0;
    if (!rc && !ej->agg_left) rc = aggregate_rest(e, ej);
    return rc;
}

/* The volume: its mip levels built here (into its own pool), the block
 * and the bricks' arrays behind the pool's used part, the bricks handed
 * out. */
static int setup_volume(engine *e, encode_job *ej)
{
    vod_source src = vod_volume_source(e->volume);
    err_info ve = {0};
    double t0 = clock_now();
    int rc = vod_prepare(&src, &ej->L, ej->p->channel, &ve);
    ej->t.fill += clock_now() - t0;
    if (rc)
        return engine_sched_fail(e, rc == -ENOMEM ? ENGINE_LIMIT : ENGINE_FAULT, rc,
                          "%s", ve.msg);
    vod_volume_info in;
    vod_volume_get_info(e->volume, &in);
    uint64_t voff = (uint64_t)((uint8_t *)e->volume - e->seg.base);
    uint64_t boff = engine_sched_align64(voff + in.bytes_used);
    uint64_t nodes = engine_sched_align64(boff + sizeof(encode_block));
    if (nodes > e->h->data_off + e->h->data_bytes) return no_room(e);
    encode_block *b = shm_at(e->seg.base, boff);
    rc = lay_out_bricks(e, ej, b, &src, nodes);
    if (rc) return rc;
    block_init(e, ej, b);
    b->source = ENCODE_VOLUME;
    b->volume_off = voff;
    b->nroots = 0;
    e->h->job_off = boff;
    e->h->job_bytes = sizeof *b;
    int pushed;
    return push_all(e, ENCODE_BRICKS, &pushed);
}

static int encode_setup(engine *e, void *job)
{
    return e->result == RESULT_VOLUME ? setup_volume(e, job) : setup_octree(e, job);
}

static int encode_take(engine *e, int i, const shm_entry *en)
{
    return engine_sched_fail(e, ENGINE_FAULT, -EPROTO,
                      "worker %d sent an entry of type %u while encoding", i,
                      en->type);
}

/* A worker's failure leaves its subtrees or bricks undone, which
 * aggregate_rest() and encode_gather() do here, so it needs no other
 * handling.  The last aggregate task done starts the second phase. */
static void encode_done(engine *e, int i, const shm_task *t, int error)
{
    encode_job *ej = e->job;
    (void)i, (void)error;
    if (t->op != ENCODE_AGGREGATE || --ej->agg_left > 0 || e->err.kind) return;
    aggregate_rest(e, ej);
}

/* How far: the mip levels' subtrees (a fifth), then the bricks handed
 * out (relaxed: estimates, nothing is read through them). */
static void encode_progress(engine *e, engine_progress *p)
{
    encode_block *b = engine_sched_block(e);
    uint64_t agg = atomic_load_explicit(&b->agg_next, memory_order_relaxed);
    uint64_t next = atomic_load_explicit(&b->next, memory_order_relaxed);
    double fa = b->nroots ? (double)(agg < b->nroots ? agg : b->nroots) / (double)b->nroots : 1;
    double fb = b->n ? (double)(next < b->n ? next : b->n) / (double)b->n : 1;
    encode_job *ej = e->job;
    p->fraction = ej->agg_left > 0 ? 0.2 * fa : 0.2 + 0.8 * fb;
    p->voxels = e->tree.voxels;
}

static int encode_rerun(engine *e, int i, const shm_task *t)
{
    (void)e, (void)i, (void)t;
    return 0;
}

static void encode_describe(const shm_task *t, char *buf, size_t len)
{
    snprintf(buf, len, t->op == ENCODE_AGGREGATE ? "the mip levels" : "brick encoding");
}

/* The records come from other processes: a missing (a worker died, or
 * the brick area was full) or malformed one is encoded again here, into
 * memory of our own, by an encoder of our own (its duplicates found as
 * the workers' are; its times into ej->t). */
static int encode_gather(engine *e, encode_job *ej, const uint8_t **data,
                         uint8_t **own)
{
    encode_block *b = engine_sched_block(e);
    const vod_params *p = ej->p;
    const vod_node *nodes = shm_at(e->seg.base, b->nodes_off);
    vod_encoded *recs = shm_at(e->seg.base, b->recs_off);
    const uint64_t *offs = shm_at(e->seg.base, b->offs_off);
    const uint8_t *bricks = shm_at(e->seg.base, b->brick_off);
    size_t bound = vod_encode_bound(&b->L, p);
    vod_encoder *enc = NULL;
    vod_source src = result_source(e);
    int rc = 0;
    for (uint64_t i = 0; i < b->n && !rc; i++) {
        uint64_t off = offs[i], same;
        uint32_t size = recs[i].size;
        if (off < b->brick_cap && size <= bound && size <= b->brick_cap - off) {
            data[i] = bricks + off;
            continue;
        }
        if (!enc) rc = vod_encoder_new(&b->L, p, &enc);
        if (!rc && !(own[i] = malloc(bound))) rc = -ENOMEM;
        if (!rc) {
            vod_brick_out o = {own[i], bound, &recs[i]};
            rc = vod_encoder_put(enc, &src, &nodes[i], i, &o, &same);
        }
        if (!rc && same != i) {
            free(own[i]);
            own[i] = NULL;
        }
        data[i] = rc || same == i ? own[i] : data[same];
    }
    if (enc) {
        vod_times t;
        vod_encoder_times(enc, &t);
        vod_times_add(&ej->t, &t);
    }
    vod_encoder_free(enc);
    return rc;
}

/* The stage times: the master's and the workers' (relaxed: read after
 * every worker's done_seq acquire). */
static void add_times(encode_block *b, encode_job *ej)
{
    if (!ej->st) return;
    vod_times w = {
        .fill = 1e-9 * (double)atomic_load_explicit(&b->ns_fill, memory_order_relaxed),
        .hash = 1e-9 * (double)atomic_load_explicit(&b->ns_hash, memory_order_relaxed),
        .compress = 1e-9 * (double)atomic_load_explicit(&b->ns_compress,
                                                        memory_order_relaxed),
    };
    vod_times_add(&ej->st->t, &w);
    vod_times_add(&ej->st->t, &ej->t);
}

/* vod_assemble says its own failures; a sink's has no message of its own. */
static int assemble(engine *e, encode_job *ej, const uint8_t **data)
{
    encode_block *b = engine_sched_block(e);
    err_info ve = {0};
    vod_assembly a = {.L = &b->L, .p = ej->p, .n = b->n,
                      .nodes = shm_at(e->seg.base, b->nodes_off),
                      .recs = shm_at(e->seg.base, b->recs_off), .data = data,
                      .sink = ej->sink, .st = ej->st, .err = &ve};
    int rc = vod_assemble(&a);
    if (!rc) return 0;
    return engine_sched_fail(e, engine_vod_failure(rc, ve.msg[0]), rc, "%s",
                      ve.msg[0] ? ve.msg : strerror(-rc));
}

/* The bricks to the caller instead of a file (engine_encode_bricks). */
static int hand_out(engine *e, encode_job *ej, const uint8_t **data)
{
    encode_block *b = engine_sched_block(e);
    vod_source src = result_source(e);
    engine_bricks out = {.L = &b->L, .src = &src, .n = b->n,
                         .nodes = shm_at(e->seg.base, b->nodes_off),
                         .recs = shm_at(e->seg.base, b->recs_off), .data = data};
    int rc = ej->deliver(ej->deliver_ud, &out);
    return rc ? engine_sched_fail(e, ENGINE_SINK, rc, "%s", strerror(-rc)) : 0;
}

static int encode_finish(engine *e, void *job, int rc)
{
    encode_job *ej = job;
    encode_block *b = engine_sched_block(e);
    if (ej->planning) { /* the job failed before the mip levels were done */
        par_join(&ej->plan);
        ej->planning = 0;
    }
    if (rc) goto out; /* set up failed: nothing was handed out */
    const uint8_t **data = calloc(b->n ? b->n : 1, sizeof *data);
    uint8_t **own = calloc(b->n ? b->n : 1, sizeof *own);
    rc = data && own ? encode_gather(e, ej, data, own) : -ENOMEM;
    if (rc) engine_sched_fail(e, ENGINE_FAULT, rc, "%s", strerror(-rc));
    else if (ej->deliver) rc = hand_out(e, ej, data);
    else rc = assemble(e, ej, data);
    if (!rc) add_times(b, ej);
    for (uint64_t i = 0; own && i < b->n; i++) free(own[i]);
    free(own);
    free(data);
out:
    *ej->err = e->err;
    return rc;
}

static const engine_kind engine_kind_encode = {
    .name = "encode",
    .id = SHM_KIND_ENCODE,
    .setup = encode_setup,
    .take = encode_take,
    .done = encode_done,
    .rerun = encode_rerun,
    .describe = encode_describe,
    .progress = encode_progress,
    .finish = encode_finish,
};

int engine_write_vod(engine *e, const vod_params *p, vod_sink *sink,
                     vod_stats *st, engine_error *err)
{
    return engine_write_vod_watched(e, p, sink, st, err, NULL);
}

static int encode_run(engine *e, encode_job *ej, const engine_sched_watch *w);

/* A job of the encode kind; the checks that need no workers first. */
int engine_write_vod_watched(engine *e, const vod_params *p, vod_sink *sink,
                             vod_stats *st, engine_error *err, const engine_sched_watch *w)
{
    encode_job ej = {.p = p, .sink = sink, .st = st, .err = err};
    return encode_run(e, &ej, w ? w : &(engine_sched_watch){0});
}

int engine_encode_bricks(engine *e, const vod_params *p, engine_deliver deliver,
                         void *ud, vod_stats *st, engine_error *err)
{
    encode_job ej = {.p = p, .st = st, .err = err, .deliver = deliver, .deliver_ud = ud};
    engine_sched_watch w = {0};
    return encode_run(e, &ej, &w);
}

static int encode_run(engine *e, encode_job *ej, const engine_sched_watch *w)
{
    const vod_params *p = ej->p;
    engine_error *err = ej->err;
    memset(err, 0, sizeof *err);
    vod_source src = result_source(e);
    int rc = -EINVAL;
    if (e->result == RESULT_NONE)
        snprintf(err->msg, sizeof err->msg,
                 "nothing to write: the last job failed or there was none");
    else if (!(rc = vod_layout_make(p, src.depth, &ej->L, err)))
        rc = vod_check_source(&src, p, err);
    if (rc) {
        err->kind = ENGINE_BAD_JOB;
        err->code = rc;
        return rc;
    }
    return engine_run(e, &engine_kind_encode, ej, w);
}
