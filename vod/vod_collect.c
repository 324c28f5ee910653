/* Phase 1's walk (vod.h: vod_collect): the non-empty brick nodes in
 * preorder.  Where the process has several CPUs and the tree is tall
 * enough, the levels above COLLECT_SPLIT levels under the root are walked
 * here, and the subtrees below them (up to 8^COLLECT_SPLIT) by every
 * thread, each into a list of its own; the lists are then copied to the
 * output at the offsets their sizes' prefix sums give.  region() only
 * reads the source, so the threads share it; the nodes and their order
 * are those of one walk. */
#include "vod.h"

#include <stdatomic.h>
#include <stdlib.h>
#include <string.h>

#include "par.h"

#define COLLECT_SPLIT 3    /* levels walked here before the subtrees */
#define COLLECT_MIN_HEIGHT 5 /* a shorter tree is walked by one thread */
#define TOP_FLAG 0x80u       /* an item of the top walk that is no root */

/* Where a walk puts its nodes: into the caller's array (up to cap, counting
 * past it), into a list that grows, or (the top walk) nodes above the
 * split as items marked TOP_FLAG and the split level's as roots. */
enum { INTO_OUT, INTO_LIST, INTO_ITEMS };

typedef struct {
    const vod_source *s;
    const vod_layout *L;
    int mode, split;
    vod_node *out;
    size_t cap, n;
    int err;          /* a list could not grow */
    uint64_t sub[32]; /* nodes in a subtree rooted at level l */
} collect_ctx;

static void ctx_init(collect_ctx *x, const vod_source *s, const vod_layout *L,
                     int mode)
{
    memset(x, 0, sizeof *x);
    x->s = s, x->L = L, x->mode = mode, x->split = -1;
    for (uint32_t l = 0; l < L->height && l < 31; l++)
        x->sub[l] = ((1ull << (3 * (l + 1))) - 1) / 7;
}

static void emit(collect_ctx *x, vod_node nd)
{
    if (x->mode == INTO_OUT) {
        if (x->n < x->cap) x->out[x->n] = nd;
        x->n++;
        return;
    }
    if (x->n == x->cap) {
        size_t c = x->cap ? 2 * x->cap : 64;
        vod_node *p = realloc(x->out, c * sizeof *p);
        if (!p) {
            x->err = 1;
            return;
        }
        x->out = p, x->cap = c;
    }
    x->out[x->n++] = nd;
}

static void collect_node(collect_ctx *x, vod_node nd);

/* The subtrees of nd's children, in child order. */
static void collect_children(collect_ctx *x, const vod_node *nd)
{
    if (nd->level == 0) return;
    for (unsigned i = 0; i < 8; i++) {
        vod_node c = {
            .preorder = nd->preorder + 1 + i * x->sub[nd->level - 1],
            .level = nd->level - 1,
            .bx = nd->bx << 1 | (i & 1u),
            .by = nd->by << 1 | ((i >> 1) & 1u),
            .bz = nd->bz << 1 | ((i >> 2) & 1u),
            .ref = nd->ref,
        };
        collect_node(x, c);
    }
}

/* Node nd (preorder, level, brick and its parent's ref set), then its
 * children's subtrees; an empty node ends its subtree.  The top walk
 * stops at the split level: the node is an item, its subtree a thread's. */
static void collect_node(collect_ctx *x, vod_node nd)
{
    int r = x->s->ops->region(x->s, x->L, &nd);
    if (r == VOD_REGION_EMPTY) return;
    nd.uniform = r == VOD_REGION_UNIFORM;
    if (!nd.uniform) nd.value = 0;
    if (x->mode == INTO_ITEMS && (int)nd.level == x->split) {
        emit(x, nd);
        return;
    }
    vod_node item = nd;
    if (x->mode == INTO_ITEMS) item.level |= TOP_FLAG;
    emit(x, item);
    collect_children(x, &nd);
}

/* The walk below the split: each root item's subtree into a list of its
 * own, then every item's nodes copied to the output at their offsets. */
typedef struct {
    const collect_ctx *top; /* its out: the items */
    vod_node **list;        /* a root's subtree, root first */
    size_t *count;          /* its nodes (an item above the split: 1) */
    size_t *at;             /* its first node's index in the output */
    atomic_size_t next;     /* the next item to walk, then to copy */
    atomic_int err;
    vod_node *out;
    size_t cap;
} subtrees;

static int is_top(const vod_node *nd) { return (nd->level & TOP_FLAG) != 0; }

static void walk_part(void *ud, unsigned k, unsigned n)
{
    subtrees *w = ud;
    (void)k, (void)n;
    for (;;) {
        /* relaxed: a counter that hands out disjoint items; the lists are
         * read after par_run's join */
        size_t i = atomic_fetch_add_explicit(&w->next, 1, memory_order_relaxed);
        if (i >= w->top->n) return;
        w->count[i] = 1;
        if (is_top(&w->top->out[i])) continue;
        collect_ctx x;
        ctx_init(&x, w->top->s, w->top->L, INTO_LIST);
        emit(&x, w->top->out[i]);
        collect_children(&x, &w->top->out[i]);
        w->list[i] = x.out;
        w->count[i] = x.n;
        /* relaxed: read after the join */
        if (x.err) atomic_store_explicit(&w->err, 1, memory_order_relaxed);
    }
}

/* An item's nodes into the output, as far as cap allows. */
static void copy_part(void *ud, unsigned k, unsigned n)
{
    subtrees *w = ud;
    (void)k, (void)n;
    for (;;) {
        /* relaxed: as in walk_part */
        size_t i = atomic_fetch_add_explicit(&w->next, 1, memory_order_relaxed);
        if (i >= w->top->n) return;
        size_t at = w->at[i], c = w->count[i];
        if (at >= w->cap) continue;
        if (c > w->cap - at) c = w->cap - at;
        if (is_top(&w->top->out[i])) {
            w->out[at] = w->top->out[i];
            w->out[at].level &= ~TOP_FLAG;
        } else {
            memcpy(w->out + at, w->list[i], c * sizeof *w->out);
        }
    }
}

/* The parallel walk on threads; (size_t)-1 when some memory was missing
 * (the caller then walks alone). */
static size_t collect_parallel(const vod_source *s, const vod_layout *L,
                               vod_node *out, size_t cap, unsigned threads)
{
    collect_ctx top;
    ctx_init(&top, s, L, INTO_ITEMS);
    top.split = (int)L->height - 1 - COLLECT_SPLIT;
    collect_node(&top, (vod_node){.level = L->height - 1});
    size_t items = top.n, total = SIZE_MAX;
    subtrees w = {.top = &top, .out = out, .cap = out ? cap : 0};
    w.list = calloc(items + 1, sizeof *w.list);
    w.count = calloc(items + 1, sizeof *w.count);
    w.at = calloc(items + 1, sizeof *w.at);
    if (!top.err && w.list && w.count && w.at) {
        atomic_init(&w.next, 0);
        atomic_init(&w.err, 0);
        par_run(threads, walk_part, &w);
        if (!atomic_load_explicit(&w.err, memory_order_relaxed)) {
            total = 0;
            for (size_t i = 0; i < items; i++) w.at[i] = total, total += w.count[i];
            atomic_store_explicit(&w.next, 0, memory_order_relaxed);
            if (w.cap) par_run(threads, copy_part, &w);
        }
    }
    for (size_t i = 0; w.list && i < items; i++) free(w.list[i]);
    free(w.list), free(w.count), free(w.at), free(top.out);
    return total;
}

size_t vod_collect(const vod_source *s, const vod_layout *L, vod_node *out,
                   size_t cap)
{
    unsigned threads = par_cpus();
    if (threads > 1 && L->height >= COLLECT_MIN_HEIGHT) {
        size_t n = collect_parallel(s, L, out, cap, threads);
        if (n != SIZE_MAX) return n;
    }
    collect_ctx x;
    ctx_init(&x, s, L, INTO_OUT);
    x.out = out;
    x.cap = out ? cap : 0;
    collect_node(&x, (vod_node){.level = L->height - 1});
    return x.n;
}
