/* vox_mpi's parts that do not talk MPI (mpi_part.h): the cut covers every
 * voxel; the book asks once per distinct brick; and the whole scheme in one
 * process (every subtree run by itself, serially and on an engine, their
 * bricks booked by content, the levels above made from their top bricks)
 * assembles the bytes of vod_write_octree over the whole grid, asking for
 * each distinct brick once. */
#include <criterion/criterion.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>

#include "engine.h"
#include "expr.h"
#include "mpi_part.h"
#include "subdiv.h"
#include "vod.h"
#include "voxel.h"

#define SPHERE "sqrt(x^2 + y^2 + z^2) - 0.8"
#define SCENE2 "sin(4*theta)*sin(8*phi) - r"
#define TORUS "sqrt((sqrt(x^2 + y^2) - 0.6)^2 + z^2) - 0.25"

static expr_tape *compile(const char *src)
{
    expr_tape *t = NULL;
    expr_error ee;
    cr_assert_eq(expr_compile(src, strlen(src), NULL, &t, &ee), 0, "%s", ee.msg);
    return t;
}

static grid_spec grid(uint32_t res)
{
    double lo[3] = {-1, -1, -1}, hi[3] = {1, 1, 1};
    grid_spec g;
    char err[128];
    cr_assert_eq(grid_make(lo, hi, res, &g, err, sizeof err), 0, "%s", err);
    return g;
}

static vod_params params(const grid_spec *g, int channel, uint32_t brick)
{
    vod_params p;
    vod_params_default(&p);
    p.channel = channel;
    p.brick = brick;
    for (int a = 0; a < 3; a++) {
        p.volume[a] = g->res[a];
        p.voxel_scale[a] = (float)g->vs;
        p.origin[a] = (float)g->lo[a];
    }
    p.metadata = "test=1\n";
    return p;
}

/* The whole grid serially, as an octree in a sparse mapping. */
static void *whole(const expr_tape *t, const grid_spec *g, octree *tree)
{
    void *arena = mmap(NULL, octree_arena_bytes(1u << 24), PROT_READ | PROT_WRITE,
                       MAP_PRIVATE | MAP_ANONYMOUS | MAP_NORESERVE, -1, 0);
    cr_assert_neq(arena, MAP_FAILED);
    octree_init(tree, arena, 1u << 24, g->depth);
    cr_assert_eq(subdiv_serial(t, g, tree), 0);
    return arena;
}

static int inside(grid_octant o, uint32_t x, uint32_t y, uint32_t z)
{
    uint32_t n = 1u << o.level;
    return x - o.x < n && y - o.y < n && z - o.z < n;
}

Test(mpi_cut, covers_every_voxel_above_a_brick)
{
    const char *shapes[] = {SPHERE, SCENE2, TORUS};
    for (int s = 0; s < 3; s++) {
        expr_tape *t = compile(shapes[s]);
        grid_spec g = grid(200);
        vod_params p = params(&g, VOXEL_CH_SURFACE, 16);
        vod_layout L;
        char err[128];
        cr_assert_eq(vod_layout_make(&p, g.depth, &L, err, sizeof err), 0);
        mpi_cut c;
        cr_assert_eq(mpi_cut_make(t, &g, &L, 24, &c), 0);
        cr_assert(c.level > (int)L.brick_log2, "cut at level %d", c.level);
        cr_assert(c.n >= 24 || c.level == (int)L.brick_log2 + 1, "%zu subtrees", c.n);
        cr_assert_eq(c.node_level, (uint32_t)c.level - L.brick_log2);
        for (size_t i = 0; i < c.n; i++) /* octants of the cut's level */
            cr_assert(c.oct[i].level == c.level &&
                      !((c.oct[i].x | c.oct[i].y | c.oct[i].z) & ((1u << c.level) - 1)));
        octree tree;
        void *arena = whole(t, &g, &tree);
        octree_iter it;
        octree_iter_init(&it, &tree);
        uint32_t x, y, z, v;
        uint64_t seen = 0;
        while (octree_iter_next(&it, &x, &y, &z, &v)) {
            size_t k = 0;
            while (k < c.n && !inside(c.oct[k], x, y, z)) k++;
            cr_assert(k < c.n, "voxel (%u,%u,%u) of shape %d is in no subtree", x, y, z, s);
            seen++;
        }
        cr_assert_gt(seen, 1000);
        munmap(arena, octree_arena_bytes(1u << 24));
        mpi_cut_free(&c);
        expr_tape_free(t);
    }
}

Test(mpi_book, asks_once_per_distinct_content)
{
    mpi_book b;
    mpi_book_init(&b);
    int fresh;
    for (uint64_t i = 0; i < 20000; i++) {
        mpi_rec r = {.key = {i * 0x9e3779b97f4a7c15ull, i}, .hash = (uint32_t)i, .size = 7};
        mpi_book_entry *e = mpi_book_get(&b, &r, &fresh);
        cr_assert(e && fresh, "entry %llu", (unsigned long long)i);
        e->state = 2;
        e->off = i;
    }
    for (uint64_t i = 0; i < 20000; i++) { /* kept through the growth */
        mpi_rec r = {.key = {i * 0x9e3779b97f4a7c15ull, i}, .hash = (uint32_t)i, .size = 7};
        mpi_book_entry *e = mpi_book_get(&b, &r, &fresh);
        cr_assert(e && !fresh && e->off == i && e->state == 2);
    }
    /* the same key with another size or hash is another brick */
    mpi_rec r = {.key = {0, 0}, .hash = 0, .size = 8};
    cr_assert(mpi_book_get(&b, &r, &fresh) && fresh);
    r.size = 7, r.hash = 1;
    cr_assert(mpi_book_get(&b, &r, &fresh) && fresh);
    cr_assert_eq(b.used, 20002);
    mpi_book_free(&b);
}

/* ---- the whole scheme in one process ---- */

typedef struct {
    mpi_book book;
    uint8_t *spill;
    size_t spill_n, spill_cap;
    mpi_rec *nodes;
    size_t n, cap;
    mpi_top *top;
    grid_octant o;
    uint64_t asked, told;
} scheme;

static void keep(scheme *s, const mpi_rec *r, const uint8_t *data)
{
    int fresh;
    mpi_book_entry *e = mpi_book_get(&s->book, r, &fresh);
    cr_assert(e);
    s->told++;
    if (fresh) {
        s->asked++;
        if (s->spill_n + r->size > s->spill_cap) {
            s->spill_cap = 2 * (s->spill_n + r->size);
            s->spill = realloc(s->spill, s->spill_cap);
        }
        memcpy(s->spill + s->spill_n, data, r->size);
        e->off = s->spill_n;
        e->state = 2;
        s->spill_n += r->size;
    }
    if (s->n == s->cap) {
        s->cap = s->cap ? 2 * s->cap : 1024;
        s->nodes = realloc(s->nodes, s->cap * sizeof *s->nodes);
    }
    s->nodes[s->n++] = *r;
}

static int deliver(void *ud, const mpi_bricks *b)
{
    scheme *s = ud;
    for (size_t i = 0; i < b->n; i++) keep(s, &b->recs[i], b->data[i]);
    if (b->n) cr_assert_eq(mpi_top_add(s->top, s->o, b->pairs, b->npairs), 0);
    return 0;
}

static int put_top(void *ud, const vod_node *n, const vod_encoded *rec, const uint8_t *data)
{
    mpi_rec r = {.preorder = n->preorder, .level = n->level, .hash = rec->hash,
                 .size = rec->size};
    mpi_key(data, rec->size, r.key);
    keep(ud, &r, data);
    return 0;
}

static int by_preorder(const void *a, const void *b)
{
    uint64_t x = ((const mpi_rec *)a)->preorder, y = ((const mpi_rec *)b)->preorder;
    return x < y ? -1 : x > y;
}

static void same_file(const char *src, uint32_t res, int channel, uint32_t brick,
                      size_t target, int workers)
{
    expr_tape *t = compile(src);
    grid_spec g = grid(res);
    vod_params p = params(&g, channel, brick);
    vod_layout L;
    char err[256];
    cr_assert_eq(vod_layout_make(&p, g.depth, &L, err, sizeof err), 0, "%s", err);
    /* the reference: the whole grid in one process */
    octree tree;
    void *arena = whole(t, &g, &tree);
    vod_membuf ref = {0};
    vod_sink rs = {vod_mem_write, &ref};
    vod_stats st;
    cr_assert_eq(vod_write_octree(&tree, &p, &rs, &st, err, sizeof err), 0, "%s", err);
    munmap(arena, octree_arena_bytes(1u << 24));

    mpi_cut c;
    cr_assert_eq(mpi_cut_make(t, &g, &L, target, &c), 0);
    scheme s = {0};
    mpi_book_init(&s.book);
    cr_assert_eq(mpi_top_new(&L, g.depth, c.node_level, &s.top), 0);
    engine *e = NULL;
    if (workers) {
        engine_opts eo = {.workers = workers, .shm_bytes = (size_t)256 << 20};
        cr_assert_eq(engine_create(&eo, &e, err, sizeof err), 0, "%s", err);
    }
    mpi_subtree_job j = {.tape = t, .grid = g, .vod = p, .node_level = c.node_level, .e = e};
    j.vod.metadata = NULL;
    for (size_t i = 0; i < c.n; i++) {
        s.o = c.oct[i];
        cr_assert_eq(mpi_subtree_run(&j, c.oct[i], deliver, &s, err, sizeof err), 0, "%s", err);
    }
    engine_destroy(e);
    cr_assert_eq(mpi_top_encode(s.top, &p, put_top, &s), 0);
    qsort(s.nodes, s.n, sizeof *s.nodes, by_preorder);
    vod_node *nodes = calloc(s.n + 1, sizeof *nodes);
    vod_encoded *recs = calloc(s.n + 1, sizeof *recs);
    const uint8_t **data = calloc(s.n + 1, sizeof *data);
    for (size_t i = 0; i < s.n; i++) {
        int fresh;
        mpi_book_entry *en = mpi_book_get(&s.book, &s.nodes[i], &fresh);
        cr_assert(!fresh && en->state == 2);
        if (i) cr_assert_gt(s.nodes[i].preorder, s.nodes[i - 1].preorder, "a node twice");
        nodes[i] = (vod_node){.preorder = s.nodes[i].preorder, .level = s.nodes[i].level};
        recs[i] = (vod_encoded){.hash = s.nodes[i].hash, .size = s.nodes[i].size};
        data[i] = s.spill + en->off;
    }
    vod_membuf got = {0};
    vod_sink gs = {vod_mem_write, &got};
    cr_assert_eq(vod_assemble(&L, &p, s.n, nodes, recs, data, &gs, NULL, err, sizeof err), 0,
                 "%s", err);
    cr_assert_eq(got.n, ref.n, "%zu bytes, want %zu (%s, %u^3, %zu subtrees of level %d)",
                 got.n, ref.n, src, res, c.n, c.level);
    cr_assert(!memcmp(got.p, ref.p, ref.n), "%s at %u^3: other bytes", src, res);
    cr_assert_eq(s.asked, st.bricks, "each distinct brick asked for once: %llu, the file "
                 "stores %llu", (unsigned long long)s.asked, (unsigned long long)st.bricks);
    cr_assert_eq(s.told, s.n);
    free(nodes), free(recs), free(data);
    free(got.p), free(ref.p);
    free(s.nodes), free(s.spill);
    mpi_book_free(&s.book);
    mpi_top_free(s.top);
    mpi_cut_free(&c);
    expr_tape_free(t);
}

Test(mpi_scheme, serial_subtrees_give_the_whole_grid_file)
{
    same_file(SPHERE, 160, VOXEL_CH_SURFACE, 16, 20, 0);
    same_file(SCENE2, 128, VOXEL_CH_SURFACE, 8, 40, 0);
    same_file(TORUS, 100, VOXEL_CH_OCCUPANCY, 4, 64, 0);
}

Test(mpi_scheme, engine_subtrees_give_the_whole_grid_file)
{
    same_file(SCENE2, 192, VOXEL_CH_SURFACE, 16, 16, 2);
    same_file(TORUS, 96, VOXEL_CH_OCCUPANCY, 8, 8, 1);
}

Test(mpi_scheme, one_subtree_is_the_whole_grid)
{
    same_file(SPHERE, 20, VOXEL_CH_SURFACE, 16, 8, 0);  /* depth 5: no cut */
    same_file(SPHERE, 64, VOXEL_CH_SURFACE, 16, 1, 1);  /* the root alone */
}
