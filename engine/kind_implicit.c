/* The implicit kind's master side: an expression's surface voxelized by
 * Figure 3's subdivision.  The job's block holds the grid and the tape;
 * the octree grows in the data area behind it, an arena whose blocks the
 * master and the workers take from one counter (implicit_block).  Tasks
 * are octants: whole subtrees below the split level (or never, with the
 * paper's schedule), which the worker builds in the arena and the master
 * links into the tree, else one octant whose kept children come back onto
 * the work stack (the paper's level-1 octants: their voxels, which the
 * master stores). */
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#include <time.h>

#include "clock.h"
#include "kind_csg.h"
#include "kind_implicit.h"
#include "master.h"
#include "subdiv.h"
#include "voxel.h"

typedef struct {
    const engine_job *job;
    engine_result *r;
    int split;             /* subtrees at and below this level */
    uint64_t done_vol, total_vol;
    uint32_t pending[GRID_MAX_DEPTH + 1]; /* octants pushed, unfinished */
    uint32_t kept[ENGINE_MAX_WORKERS];    /* octants the task sent back */
    uint64_t stored;       /* voxels taken from the queues */
    uint64_t cells;        /* cells of the subtrees linked */
    uint32_t end;          /* and the end of the cells they lie in */
} implicit_job;

#define NEED_DOUBT 4.0 /* see implicit_progress */

static uint64_t volume(int level) { return 1ull << (3 * level); }

/* Bytes of the data area up to the octree's first `cells` cells. */
static uint64_t tree_bytes(engine *e, uint64_t cells)
{
    uint64_t off = (uint64_t)((uint8_t *)e->tree.cells - e->seg.base);
    return off - e->h->data_off + cells * sizeof(octree_cell);
}

/* The arena's blocks handed out so far (to the master and the workers). */
static unsigned blocks_out(engine *e)
{
    implicit_block *b = engine_sched_block(e);
    /* relaxed: see implicit_block.next_block */
    return atomic_load_explicit(&b->next_block, memory_order_relaxed);
}

/* Cells up to the end of the arena's first n blocks (the root's cell
 * first; all of them once every block is out). */
static uint32_t cells_below(engine *e, unsigned n)
{
    implicit_block *b = engine_sched_block(e);
    return n >= b->blocks ? b->tree_cells : 1 + n * OCTREE_BLOCK_CELLS;
}

/* Cells of the arena handed out so far: every index in the tree is below
 * it. */
static uint32_t arena_used(engine *e)
{
    return cells_below(e, blocks_out(e));
}

/* Bytes of the data area up to the blocks surely full: those handed out
 * but one open block a writer (the master and each worker). */
static uint64_t full_bytes(engine *e)
{
    unsigned n = blocks_out(e), open = (unsigned)e->n + 1;
    implicit_block *b = engine_sched_block(e);
    if (n >= b->blocks) return tree_bytes(e, cells_below(e, n));
    return n > open ? tree_bytes(e, cells_below(e, n - open)) : 0;
}

static int no_cells(engine *e)
{
    return engine_sched_fail(e, ENGINE_LIMIT, -ENOMEM,
                             "the octree needs more than %u cells; raise the "
                             "shared memory size (now %zu MiB)",
                             e->tree.capacity, e->seg.bytes >> 20);
}

/* The master's blocks (octree_share). */
static int master_grab(void *ud, uint32_t *first, uint32_t *end)
{
    engine *e = ud;
    return implicit_claim(e->seg.base, engine_sched_block(e), IMPLICIT_MASTER, first, end);
}

static int push_octant(engine *e, implicit_job *ij, grid_octant o)
{
    shm_task t = {.kind = SHM_KIND_IMPLICIT,
                  .op = ij->job->schedule == ENGINE_SCHED_PAPER || o.level > ij->split
                            ? IMPLICIT_CHILDREN
                            : IMPLICIT_SUBTREE};
    memcpy(t.arg, &o, sizeof o);
    int rc = engine_sched_push(e, &t);
    if (!rc) ij->pending[o.level]++;
    return rc;
}

static int outside_res(engine *e, unsigned x, unsigned y, unsigned z)
{
    const implicit_block *b = engine_sched_block(e);
    const uint32_t *res = b->grid.res;
    return x >= res[0] || y >= res[1] || z >= res[2];
}

/* Is (x, y, z) inside octant o? */
static int inside(grid_octant o, unsigned x, unsigned y, unsigned z)
{
    unsigned n = 1u << o.level;
    return x - o.x < n && y - o.y < n && z - o.z < n;
}

static int take_octants(engine *e, int i, const shm_entry *en)
{
    implicit_job *ij = e->job;
    const shm_task *t = &e->ms[i].task;
    grid_octant task = implicit_octant(t), o = ((const grid_octant *)en->payload)[0];
    if (en->count != 1 || t->op != IMPLICIT_CHILDREN || o.level + 1 != task.level ||
        !inside(task, o.x, o.y, o.z) || (o.x | o.y | o.z) & ((1u << o.level) - 1) ||
        outside_res(e, o.x, o.y, o.z))
        return engine_sched_fail(e, ENGINE_FAULT, -EPROTO,
                          "worker %d sent octant (%u,%u,%u) level %u, not a "
                          "child of its task",
                          i, o.x, o.y, o.z, o.level);
    ij->kept[i]++;
    return push_octant(e, ij, o);
}

/* The paper schedule's level-1 octants: one voxel per entry, stored here. */
static int take_voxels(engine *e, int i, const shm_entry *en)
{
    implicit_job *ij = e->job;
    const shm_task *t = &e->ms[i].task;
    grid_octant task = implicit_octant(t);
    uint32_t n = en->count; /* read once: the worker's memory */
    if (n != 1 || t->op != IMPLICIT_CHILDREN || task.level != 1)
        return engine_sched_fail(e, ENGINE_FAULT, -EPROTO,
                          "worker %d sent a batch of %u voxels", i, n);
    grid_voxel v = ((const grid_voxel *)en->payload)[0];
    if (!inside(task, v.x, v.y, v.z) || outside_res(e, v.x, v.y, v.z) || v.value == 0)
        return engine_sched_fail(e, ENGINE_FAULT, -EPROTO,
                          "worker %d sent voxel (%u,%u,%u) outside its "
                          "task", i, v.x, v.y, v.z);
    ij->stored++;
    return octree_store(&e->tree, v.x, v.y, v.z, v.value) ? no_cells(e) : 0;
}

/* Is cell c in a block worker i claimed? */
static int claimed_by(engine *e, int i, uint32_t c)
{
    implicit_block *b = engine_sched_block(e);
    uint32_t k = (c - 1) / OCTREE_BLOCK_CELLS;
    if (c == 0 || c >= arena_used(e) || k >= b->blocks) return 0;
    /* relaxed: see implicit_claim */
    return atomic_load_explicit(&implicit_owners(e->seg.base, b)[k], memory_order_relaxed) ==
           (uint16_t)(i + 1);
}

/* A subtree a worker built: checked as far as it cheaply can be (its
 * octant the task's, its root in a block the worker claimed, its counts
 * possible), its root linked into the tree.  The cells below the root are
 * the worker's; the tree's readers bound every index (octree_child). */
static int take_subtree(engine *e, int i, const shm_entry *en)
{
    implicit_job *ij = e->job;
    const shm_task *t = &e->ms[i].task;
    grid_octant o = implicit_octant(t);
    implicit_subtree s;
    uint32_t n = en->count; /* read once: the worker's memory */
    memcpy(&s, en->payload, sizeof s);
    if (n != 1 || t->op != IMPLICIT_SUBTREE || memcmp(&s.o, &o, sizeof o) ||
        s.voxels == 0 || s.voxels > volume(o.level) || s.cells < o.level ||
        s.cells > e->tree.capacity || !claimed_by(e, i, s.root) || s.end <= s.root ||
        s.end > arena_used(e))
        return engine_sched_fail(e, ENGINE_FAULT, -EPROTO,
                          "worker %d sent a subtree (root %u, %u cells, %llu voxels) "
                          "that is not its octant's (%u,%u,%u) level %u", i, s.root,
                          s.cells, (unsigned long long)s.voxels, o.x, o.y, o.z, o.level);
    int rc = octree_link(&e->tree, (uint32_t[3]){o.x, o.y, o.z}, o.level - 1, s.root, s.voxels);
    if (rc == -ENOMEM) return no_cells(e);
    if (rc)
        return engine_sched_fail(e, ENGINE_FAULT, -EPROTO,
                          "worker %d sent a second subtree for octant (%u,%u,%u) level %u",
                          i, o.x, o.y, o.z, o.level);
    /* the whole tree's subtree: its root's entries were copied to cell 1 */
    ij->cells += s.cells - (o.level == e->tree.depth);
    ij->stored += s.voxels;
    if (s.end > ij->end) ij->end = s.end;
    return 0;
}

static int implicit_take(engine *e, int i, const shm_entry *en)
{
    uint32_t type = en->type; /* read once: the worker's memory */
    if (type == IMPLICIT_OCTANTS) return take_octants(e, i, en);
    if (type == IMPLICIT_VOXELS) return take_voxels(e, i, en);
    if (type == IMPLICIT_BUILT) return take_subtree(e, i, en);
    return engine_sched_fail(e, ENGINE_FAULT, -EPROTO,
                      "worker %d sent an entry of type %u", i, type);
}

static void implicit_done(engine *e, int i, const shm_task *t, int error)
{
    implicit_job *ij = e->job;
    implicit_block *b = engine_sched_block(e);
    /* relaxed: see implicit_block.next_block */
    if (error == -ENOMEM && t->op == IMPLICIT_SUBTREE &&
        atomic_load_explicit(&b->next_block, memory_order_relaxed) >= b->blocks)
        no_cells(e); /* the arena ran out under the worker */
    else if (error)
        engine_sched_fail(e, ENGINE_FAULT, error, "worker %d failed: %s", i,
                   strerror(-error));
    int l = implicit_octant(t).level;
    ij->pending[l]--;
    if (t->op == IMPLICIT_SUBTREE || l == 1)
        ij->done_vol += volume(l);
    else
        ij->done_vol += volume(l) - (uint64_t)ij->kept[i] * volume(l - 1);
    ij->kept[i] = 0;
}

/* The job's end (engine_kind.tail): a subtree above TAIL_LEVEL handed out
 * as its children instead, which come back as subtrees one level finer,
 * so that the last tasks are small and the workers end together (issue
 * 24: the last level-6 subtrees took up to a few ms of one worker while
 * the other had none).  Only once no octant above the split is still out:
 * at the job's start the stack is short too, but more is coming.  The
 * same voxels: a task of children and a subtree test every octant with
 * the same pruned tapes (subdiv.c). */
#define TAIL_LEVEL 4

static void implicit_tail(engine *e, shm_task *t)
{
    const implicit_job *ij = e->job;
    if (t->op != IMPLICIT_SUBTREE || implicit_octant(t).level <= TAIL_LEVEL ||
        ij->job->split_level > 0) /* the caller's tasks, as it asked */
        return;
    /* octants above the split still out (the job's start): more to come */
    for (int l = ij->split + 1; l <= GRID_MAX_DEPTH; l++)
        if (ij->pending[l]) return;
    t->op = IMPLICIT_CHILDREN;
}

/* The kernel is deterministic: a re-run gives the same entries. */
static int implicit_rerun(engine *e, int i, const shm_task *t)
{
    (void)e, (void)i, (void)t;
    return 1;
}

static void implicit_describe(const shm_task *t, char *buf, size_t len)
{
    grid_octant o = implicit_octant(t);
    snprintf(buf, len, "octant (%u,%u,%u) level %u", o.x, o.y, o.z, o.level);
}

static int top_pending(const implicit_job *ij)
{
    for (int l = GRID_MAX_DEPTH; l > 0; l--)
        if (ij->pending[l]) return l;
    return 0;
}

static void implicit_progress(engine *e, engine_progress *p)
{
    const implicit_job *ij = e->job;
    double f = (double)ij->done_vol / (double)ij->total_vol;
    p->fraction = f > 1.0 ? 1.0 : f;
    p->level = top_pending(ij);
    p->voxels = e->tree.voxels;
    p->shm_used = tree_bytes(e, arena_used(e)); /* every writer's blocks */
    /* The octree's need, extrapolated from the volume done (culled space
     * included): used / fraction.  What is done may be denser than what
     * is left (up to 3 times on a shape built to fool it, under 1.8 on the
     * examples), so the need told is a NEED_DOUBT-th of that, and only once
     * the octree holds a 64th of the data area: a job that fits is not
     * stopped, and one that does not (x*0 at 4096^3) is stopped at once.
     * Used counts the full blocks only (full_bytes): each writer's open
     * block is mostly empty at first, and the master counts a task's
     * volume as done only once it has taken its end, so early in a job
     * with a small segment the open blocks over the volume done said
     * "too big" of a job that fits. */
    uint64_t full = full_bytes(e);
    if (f > 0 && full >= e->h->data_bytes / 64)
        p->shm_need = (uint64_t)((double)full / f / NEED_DOUBT);
}

/* The data area: the job's block, its tape, the arena's block owners and
 * cells; the master's tree in the arena, its blocks shared (the counter
 * at 1: block 0, the root's, is the master's).  0, or engine_sched_fail's
 * return. */
static int implicit_layout(engine *e, const engine_job *j)
{
    shm_header *h = e->h;
    size_t tb = expr_tape_bytes(j->tape);
    uint64_t end = h->data_off + h->data_bytes;
    uint64_t tape_off = engine_sched_align64(h->data_off + sizeof(implicit_block));
    uint64_t owners_off = engine_sched_align64(tape_off + tb);
    /* an owner per block the space left could hold (the cells get the rest) */
    uint64_t left = end > owners_off ? end - owners_off : 0;
    uint64_t most = left / octree_arena_bytes(OCTREE_BLOCK_CELLS) + 1;
    uint64_t tree_off = engine_sched_align64(owners_off + most * sizeof(uint16_t));
    if (tree_off + 2 * sizeof(octree_cell) > end)
        return engine_sched_fail(e, ENGINE_LIMIT, -ENOMEM,
                          "the expression (%zu bytes compiled) leaves no room "
                          "for the octree; raise the shared memory size", tb);
    uint64_t cap = (end - tree_off) / sizeof(octree_cell);
    if (cap > UINT32_MAX) cap = UINT32_MAX;
    implicit_block *b = shm_at(e->seg.base, h->data_off);
    b->grid = j->grid;
    b->tape_off = tape_off;
    b->tape_bytes = tb;
    b->owners_off = owners_off;
    b->tree_off = tree_off;
    b->tree_cells = (uint32_t)cap;
    b->blocks = (uint32_t)((cap - 2 + OCTREE_BLOCK_CELLS) / OCTREE_BLOCK_CELLS);
    memcpy(shm_at(e->seg.base, tape_off), j->tape, tb);
    /* relaxed: no worker runs a task of the job yet; the task_seq release
     * of its first publishes these */
    _Atomic uint16_t *owners = implicit_owners(e->seg.base, b);
    for (uint32_t k = 0; k < b->blocks; k++)
        atomic_store_explicit(&owners[k], k ? 0 : IMPLICIT_MASTER, memory_order_relaxed);
    atomic_store_explicit(&b->next_block, 1, memory_order_relaxed);
    h->job_off = h->data_off;
    h->job_bytes = tree_off - h->data_off;
    octree_init(&e->tree, shm_at(e->seg.base, tree_off), (uint32_t)cap, j->grid.depth);
    octree_share(&e->tree, master_grab, e);
    return 0;
}

static int implicit_setup(engine *e, void *job)
{
    implicit_job *ij = job;
    const engine_job *j = ij->job;
    e->result = RESULT_NONE;
    e->tree_top = -1;
    engine_sched_hold(e, 0); /* the last job's result: overwritten now */
    if (!j->tape) return engine_sched_fail(e, ENGINE_BAD_JOB, -EINVAL, "the job has no tape");
    if (grid_check(&j->grid))
        return engine_sched_fail(e, ENGINE_BAD_JOB, -EINVAL, "the job's grid is invalid");
    int rc = implicit_layout(e, j);
    if (rc) return rc;
    int depth = j->grid.depth;
    grid_octant root = j->root ? *j->root : grid_root(&j->grid);
    if (root.level < 1 || root.level > depth || !inside(grid_root(&j->grid), root.x, root.y, root.z) ||
        (root.x | root.y | root.z) & ((1u << root.level) - 1))
        return engine_sched_fail(e, ENGINE_BAD_JOB, -EINVAL, "the job's root octant is not one of its grid");
    ij->total_vol = volume(root.level);
    ij->split = j->split_level > 0    ? j->split_level
                : root.level - 3 < 1 ? 1
                : root.level - 3 > 6 ? 6
                                     : root.level - 3;
    return push_octant(e, ij, root);
}

static int implicit_finish(engine *e, void *job, int rc)
{
    implicit_job *ij = job;
    engine_result *r = ij->r;
    engine_sched_job_totals(e, r);
    r->seconds = clock_now() - e->t0;
    if (rc) return engine_sched_job_failed(e, r, rc);
    e->result = RESULT_OCTREE;
    /* the subtrees' roots are at the split level or below it (the tail's),
     * the cells above them the master's; the paper schedule's are all its */
    e->tree_top = ij->job->schedule == ENGINE_SCHED_PAPER ? 0
                  : ij->split < e->tree.depth           ? ij->split
                                                        : -1;
    /* the octree stays for the encode kind: the cells up to the last one
     * in the tree (the master's, the subtrees'), whose end bounds the
     * tree's indices; the blocks' unused tails past it go back */
    e->tree.used = ij->end > e->tree.next ? ij->end : e->tree.next;
    engine_sched_hold(e, tree_bytes(e, e->tree.used));
    r->voxels = e->tree.voxels;
    r->cells = 1 + e->tree.taken + (uint32_t)ij->cells; /* cell 0 too */
    r->duplicates = ij->stored - e->tree.voxels;
    return 0;
}

/* ---- the pipeline's side (master.h) ---- */

static int implicit_domain(const engine_pipeline_job *job, double lo[3], double hi[3],
                           engine_pipeline_report *r)
{
    (void)lo, (void)hi; /* the job's own */
    if (job->vod.channel == VOXEL_CH_DISTANCE && engine_pipeline_band(job) > CSG_DIST_MAX_BAND)
        return engine_pipeline_fail(r, ENGINE_BAD_JOB, -EINVAL, "a band of %u voxels: at most %u",
                             engine_pipeline_band(job), CSG_DIST_MAX_BAND);
    if (job->vod.channel == VOXEL_CH_DISTANCE && !job->implicit.source)
        return engine_pipeline_fail(r, ENGINE_BAD_JOB, -EINVAL,
                             "the distance job has no expression text");
    return job->implicit.tape ? 0
                              : engine_pipeline_fail(r, ENGINE_BAD_JOB, -EINVAL,
                                              "the job has no expression");
}

static void implicit_meta(const engine_pipeline_job *job, job_meta *m, char *pairs, size_t len)
{
    if (job->vod.channel == VOXEL_CH_DISTANCE) { /* what a level set's readers need */
        snprintf(pairs, len, "distance_band=%u\ndistance_units=world\n", engine_pipeline_band(job));
        m->kind_pairs = pairs;
    }
    m->source = job->implicit.source;
    m->source_len = job->implicit.source_len;
    m->source_name = job->implicit.source_name;
}

/* An implicit job's distance runs as the csg kind's: a tree of one
 * implicit leaf (the job's text), its k the band; csg_dist does the rest
 * (the octree keeps nothing of the space it prunes, whose sign a distance
 * needs). */
static int distance_tree(const engine_pipeline_job *job, csg_tree **out)
{
    csg_tree *t = calloc(1, sizeof *t);
    char *text = malloc(job->implicit.source_len + 1);
    if (!t || !text) {
        free(t);
        free(text);
        return -ENOMEM;
    }
    memcpy(text, job->implicit.source, job->implicit.source_len);
    text[job->implicit.source_len] = 0;
    t->n = 1;
    t->text = text;
    t->text_len = job->implicit.source_len;
    csg_node *n = &t->node[0];
    n->kind = CSG_IMPLICIT;
    n->a = n->b = -1;
    n->expr_len = (uint32_t)job->implicit.source_len;
    n->k = engine_pipeline_band(job);
    snprintf(n->name, sizeof n->name, "implicit");
    *out = t;
    return 0;
}

static int implicit_rewrite(engine_pipeline_job *run, csg_tree **owned)
{
    if (run->vod.channel != VOXEL_CH_DISTANCE) return 0;
    int rc = distance_tree(run, owned);
    if (rc) return rc;
    run->kind = &engine_kind_csg; /* its input replaces the expression's */
    run->csg = (engine_csg_input){.tree = *owned};
    return 0;
}

#define SERIAL_CELLS (1u << 27) /* 4 GiB of address space, not of memory */

/* The serial algorithm: its octree in a sparse private mapping, touched
 * only as cells are handed out. */
static int implicit_serial(engine_pipeline_job *job, const vod_params *v, vod_sink *sink,
                           engine_pipeline_report *r)
{
    size_t bytes = octree_arena_bytes(SERIAL_CELLS);
    void *arena = mmap(NULL, bytes, PROT_READ | PROT_WRITE,
                       MAP_PRIVATE | MAP_ANONYMOUS | MAP_NORESERVE, -1, 0);
    r->stage = ENGINE_PIPELINE_VOXELIZE;
    if (arena == MAP_FAILED)
        return engine_pipeline_fail(r, ENGINE_FAULT, -errno, "cannot map the octree: %s",
                             strerror(errno));
    octree t;
    octree_init(&t, arena, SERIAL_CELLS, r->grid.depth);
    double t0 = clock_now();
    int rc = subdiv_serial(job->implicit.tape, &r->grid, &t);
    r->t_voxelize = clock_now() - t0;
    r->voxels = t.voxels;
    if (rc == -ENOMEM)
        engine_pipeline_fail(r, ENGINE_LIMIT, rc, "the octree outgrew its 4 GiB arena");
    else if (rc)
        engine_pipeline_fail(r, ENGINE_FAULT, rc, "%s", strerror(-rc));
    if (!rc) rc = engine_pipeline_write_serial(&t, NULL, v, sink, r);
    munmap(arena, bytes);
    return rc;
}

static int implicit_voxelize(engine *e, engine_pipeline_job *job, const engine_sched_watch *w,
                             engine_result *er, engine_pipeline_report *r)
{
    engine_job ej = {.tape = job->implicit.tape, .grid = r->grid,
                     .schedule = job->schedule, .progress = w->progress,
                     .ud = w->ud, .cancel = w->cancel};
    return engine_voxelize(e, &ej, er);
}

const engine_kind engine_kind_implicit = {
    .name = "implicit",
    .id = SHM_KIND_IMPLICIT,
    .setup = implicit_setup,
    .take = implicit_take,
    .done = implicit_done,
    .rerun = implicit_rerun,
    .tail = implicit_tail,
    .prefetch = 1,
    .describe = implicit_describe,
    .progress = implicit_progress,
    .finish = implicit_finish,
    .domain = implicit_domain,
    .meta = implicit_meta,
    .rewrite = implicit_rewrite,
    .serial = implicit_serial,
    .voxelize = implicit_voxelize,
};

int engine_voxelize(engine *e, const engine_job *job, engine_result *r)
{
    implicit_job ij = {.job = job, .r = r};
    engine_sched_watch w = {.progress = job->progress, .ud = job->ud, .cancel = job->cancel};
    return engine_sched_run_job(e, &engine_kind_implicit, &ij, &w, r);
}
