/* vox_mpi's parts that do not talk MPI (mpi_part.h): the cut covers every
 * voxel; the book asks once per distinct brick; and the whole scheme in one
 * process (every subtree run by itself, serially and on an engine, their
 * bricks booked by content, the levels above made from their top bricks)
 * assembles the bytes of vod_write_octree over the whole grid, asking for
 * each distinct brick once.  For mesh and CSG jobs the same against
 * engine_pipeline_run's file, each column's triangles through mpi_mesh_part and
 * mpi_mesh_view, and the tree through csg_tree_pack and csg_tree_unpack;
 * damaged trees and meshes are refused. */
#include <criterion/criterion.h>
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>

#include "engine.h"
#include "expr.h"
#include "mpi_part.h"
#include "pipeline.h"
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
    err_info err = {0};
    cr_assert_eq(grid_make(lo, hi, res, &g, &err), 0, "%s", err.msg);
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
        err_info err = {0};
        cr_assert_eq(vod_layout_make(&p, g.depth, &L, &err), 0);
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
    int columns;
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

/* The task's nodes booked, each of its subtrees' top bricks to the top:
 * an octant task's own, or (columns) any octant of its column. */
static int deliver(void *ud, const mpi_bricks *b)
{
    scheme *s = ud;
    for (size_t i = 0; i < b->n; i++) keep(s, &b->recs[i], b->data[i]);
    size_t at = 0;
    cr_assert(b->n || !b->ntops);
    for (size_t i = 0; i < b->ntops; i++) {
        grid_octant o = b->tops[i].o;
        cr_assert(o.level == s->o.level && o.x == s->o.x && o.y == s->o.y &&
                  (o.z == s->o.z || s->columns), "a top brick outside its task");
        cr_assert_eq(mpi_top_add(s->top, o, b->pairs + at, b->tops[i].npairs), 0);
        at += b->tops[i].npairs;
    }
    cr_assert_eq(at, b->npairs);
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

/* The file assemble_same must give: its bytes (freed there), its distinct
 * bricks, and the job's name for the messages. */
typedef struct {
    vod_membuf file;
    uint64_t bricks;
    const char *src;
} want_file;

static void assemble_same(scheme *sp, const vod_layout *Lp, const vod_params *pp,
                          const want_file *want, const mpi_cut *cp);

static void same_file(const char *src, uint32_t res, int channel, uint32_t brick,
                      size_t target, int workers)
{
    expr_tape *t = compile(src);
    grid_spec g = grid(res);
    vod_params p = params(&g, channel, brick);
    vod_layout L;
    err_info err = {0};
    err_info se = {0};
    cr_assert_eq(vod_layout_make(&p, g.depth, &L, &err), 0, "%s", err.msg);
    /* the reference: the whole grid in one process */
    octree tree;
    void *arena = whole(t, &g, &tree);
    vod_membuf ref = {0};
    vod_sink rs = {vod_mem_write, &ref};
    vod_stats st;
    cr_assert_eq(vod_write_octree(&tree, &p, &rs, &st, &err), 0, "%s", err.msg);
    munmap(arena, octree_arena_bytes(1u << 24));

    mpi_cut c;
    cr_assert_eq(mpi_cut_make(t, &g, &L, target, &c), 0);
    scheme s = {0};
    mpi_book_init(&s.book);
    cr_assert_eq(mpi_top_new(&L, g.depth, c.node_level, &s.top), 0);
    engine *e = NULL;
    if (workers) {
        engine_opts eo = {.workers = workers, .shm_bytes = (size_t)256 << 20};
        err_info ee = {0};
        cr_assert_eq(engine_create(&eo, &e, &ee), 0, "%s", ee.msg);
    }
    mpi_subtree_job j = {.kind = MPI_KIND_IMPLICIT, .tape = t, .grid = g, .vod = p, .node_level = c.node_level, .e = e};
    j.vod.metadata = NULL;
    for (size_t i = 0; i < c.n; i++) {
        s.o = c.oct[i];
        cr_assert_eq(mpi_subtree_run(&j, c.oct[i], deliver, &s, &se), 0, "%s", se.msg);
    }
    engine_destroy(e);
    assemble_same(&s, &L, &p, &(want_file){ref, st.bricks, src}, &c);
    mpi_cut_free(&c);
    expr_tape_free(t);
}

/* The levels above, then every node in preorder assembled: want's bytes,
 * each of its distinct bricks asked for once. */
static void assemble_same(scheme *sp, const vod_layout *Lp, const vod_params *pp,
                          const want_file *want, const mpi_cut *cp)
{
    scheme s = *sp;
    vod_layout L = *Lp;
    vod_params p = *pp;
    vod_membuf ref = want->file;
    uint64_t bricks = want->bricks;
    const char *src = want->src;
    mpi_cut c = *cp;
    uint32_t res = p.volume[0];
    err_info err = {0};
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
    vod_assembly a = {.L = &L, .p = &p, .n = s.n, .nodes = nodes, .recs = recs,
                      .data = data, .sink = &gs, .err = &err};
    cr_assert_eq(vod_assemble(&a), 0,
                 "%s", err.msg);
    cr_assert_eq(got.n, ref.n, "%zu bytes, want %zu (%s, %u^3, %zu subtrees of level %d)",
                 got.n, ref.n, src, res, c.n, c.level);
    cr_assert(!memcmp(got.p, ref.p, ref.n), "%s at %u^3: other bytes", src, res);
    cr_assert_eq(s.asked, bricks, "each distinct brick asked for once: %llu, the file "
                 "stores %llu", (unsigned long long)s.asked, (unsigned long long)bricks);
    cr_assert_eq(s.told, s.n);
    free(nodes), free(recs), free(data);
    free(got.p), free(ref.p);
    free(s.nodes), free(s.spill);
    mpi_book_free(&s.book);
    mpi_top_free(s.top);
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

/* ---- mesh and CSG jobs ---- */

/* A torus of 2 nu nv triangles, closed, counter-clockwise from outside;
 * with drop, every drop-th triangle left out. */
static mesh torus(uint32_t nu, uint32_t nv, uint32_t drop)
{
    mesh m = {0};
    m.vertices = calloc((size_t)nu * nv, sizeof *m.vertices);
    m.triangles = calloc(2 * (size_t)nu * nv, sizeof *m.triangles);
    for (uint32_t i = 0; i < nu; i++)
        for (uint32_t j = 0; j < nv; j++) {
            double u = 2 * M_PI * i / nu, v = 2 * M_PI * j / nv;
            float *p = m.vertices[m.n_vertices++];
            p[0] = (float)((0.6 + 0.25 * cos(v)) * cos(u));
            p[1] = (float)((0.6 + 0.25 * cos(v)) * sin(u));
            p[2] = (float)(0.25 * sin(v));
        }
    uint32_t k = 0;
    for (uint32_t i = 0; i < nu; i++)
        for (uint32_t j = 0; j < nv; j++) {
            uint32_t a = i * nv + j, b = (i + 1) % nu * nv + j;
            uint32_t c = (i + 1) % nu * nv + (j + 1) % nv, d = i * nv + (j + 1) % nv;
            uint32_t t[2][3] = {{a, b, c}, {a, c, d}};
            for (int h = 0; h < 2; h++)
                if (!drop || ++k % drop) memcpy(m.triangles[m.n_triangles++], t[h], 12);
        }
    for (int a = 0; a < 3; a++) m.lo[a] = m.hi[a] = m.vertices[0][a];
    for (uint32_t i = 0; i < m.n_vertices; i++)
        for (int a = 0; a < 3; a++) {
            m.lo[a] = fminf(m.lo[a], m.vertices[i][a]);
            m.hi[a] = fmaxf(m.hi[a], m.vertices[i][a]);
        }
    return m;
}

static void torus_free(mesh *m)
{
    free(m->vertices);
    free(m->triangles);
}

/* Task o of a mesh job: its triangles as rank 0 sends them, viewed as a
 * rank does; NULL when the column has none (rank 0 drops it). */
static uint8_t *column_mesh(const mesh *m, const mesh_bins *bins, const grid_spec *g,
                            grid_octant o, int keep_empty, mesh *part)
{
    uint32_t t[4];
    mpi_column_tiles(g, o, t);
    uint8_t *buf;
    size_t n;
    cr_assert_eq(mpi_mesh_part(m, bins, bins->start ? t : NULL, &buf, &n), 0);
    uint32_t head[2];
    memcpy(head, buf, sizeof head);
    /* a column without a triangle: none of its voxels is set, but for the
     * distance, whose every voxel is (the band's width beyond it) */
    if (!head[1] && !keep_empty) {
        free(buf);
        return NULL;
    }
    cr_assert_eq(mpi_mesh_view(buf, n, part), 0);
    cr_assert_eq(part->n_triangles, head[1]);
    return buf;
}

/* job (a mesh or CSG one) run task by task, as vox_mpi's ranks run it
 * (j: the rank's part, its kind and input), against engine_pipeline_run's file;
 * the columns without a triangle that ran (a distance's). */
static size_t same_job(const engine_pipeline_job *job, mpi_subtree_job j, size_t target,
                       int workers)
{
    char meta[JOB_META_MAX];
    err_info err = {0};
    err_info se = {0};
    vod_params v;
    engine_pipeline_report r, rr;
    vod_membuf ref = {0};
    vod_sink rs = {vod_mem_write, &ref};
    cr_assert_eq(engine_pipeline_plan(job, &r, &v, meta), 0, "%s", r.err.msg);
    cr_assert_eq(engine_pipeline_run(NULL, job, &rs, &rr), 0, "%s", rr.err.msg);
    vod_layout L;
    cr_assert_eq(vod_layout_make(&v, r.grid.depth, &L, &err), 0, "%s", err.msg);
    int columns = j.kind == MPI_KIND_MESH;
    mpi_cut c;
    cr_assert_eq(mpi_cut_grid(&r.grid, &L, target, columns ? 6 : 4, columns, &c), 0);
    cr_assert(c.n >= target || c.level == r.grid.depth ||
              c.level == (columns ? 6 : 4) || c.level == (int)L.brick_log2 + 1);
    scheme s = {.columns = columns};
    mpi_book_init(&s.book);
    cr_assert_eq(mpi_top_new(&L, r.grid.depth, c.node_level, &s.top), 0);
    engine *e = NULL;
    if (workers) {
        engine_opts eo = {.workers = workers, .shm_bytes = (size_t)256 << 20};
        err_info ee = {0};
        cr_assert_eq(engine_create(&eo, &e, &ee), 0, "%s", ee.msg);
    }
    j.grid = r.grid, j.vod = v, j.vod.metadata = NULL, j.node_level = c.node_level, j.e = e;
    mesh_bins bins = {0};
    size_t empties = 0;
    if (columns && j.mesh_opts.repair != MESH_REPAIR_WINDING)
        cr_assert_eq(mesh_bin(job->mesh.mesh, &r.grid, &j.mesh_opts, NULL, 1, &bins), 0);
    for (size_t i = 0; i < c.n; i++) {
        s.o = c.oct[i];
        mesh part;
        int dist = v.channel == VOXEL_CH_DISTANCE;
        uint8_t *buf = columns ? column_mesh(job->mesh.mesh, &bins, &r.grid, c.oct[i], dist, &part)
                               : NULL;
        if (columns && !buf) continue;
        empties += columns && !part.n_triangles;
        j.mesh = &part;
        cr_assert_eq(mpi_subtree_run(&j, c.oct[i], deliver, &s, &se), 0, "%s", se.msg);
        free(buf);
    }
    engine_destroy(e);
    assemble_same(&s, &L, &v, &(want_file){ref, rr.st.bricks, columns ? "a mesh" : "a tree"},
                  &c);
    mesh_bins_free(&bins);
    mpi_cut_free(&c);
    return empties;
}

static void same_mesh(uint32_t res, mesh_vox_opts o, uint32_t drop, size_t target, int workers)
{
    mesh m = torus(24, 12, drop);
    engine_pipeline_job job = {.kind = &engine_kind_mesh, .mesh = {.mesh = &m, .opts = o, .fit = 1},
                        .res = res};
    vod_params_default(&job.vod);
    job.vod.channel = o.channel;
    /* the repair as rank 0 runs it: none for the closed torus */
    mpi_subtree_job j = {.kind = MPI_KIND_MESH, .mesh_opts = o};
    if (!drop) j.mesh_opts.repair = MESH_REPAIR_NONE;
    same_job(&job, j, target, workers);
    torus_free(&m);
}

Test(mpi_scheme, mesh_columns_give_the_whole_grid_file)
{
    mesh_vox_opts solid = {.channel = VOXEL_CH_OCCUPANCY};
    same_mesh(200, solid, 0, 8, 0);
    same_mesh(130, (mesh_vox_opts){.channel = VOXEL_CH_DENSITY, .supersample = 3}, 0, 4, 2);
    same_mesh(150, (mesh_vox_opts){.mode = MESH_SURFACE, .channel = VOXEL_CH_SURFACE}, 0, 8, 1);
    same_mesh(200, (mesh_vox_opts){.repair = MESH_REPAIR_VOTE, .channel = VOXEL_CH_OCCUPANCY},
              37, 8, 1);
    same_mesh(100, (mesh_vox_opts){.repair = MESH_REPAIR_WINDING, .channel = VOXEL_CH_OCCUPANCY},
              37, 4, 0);
}

/* The distance: every column handed out, those without a triangle too
 * (in a box larger than the torus), the levels above the float mean. */
static void same_distance(uint32_t res, uint32_t band, size_t target, int workers)
{
    mesh m = torus(24, 12, 0);
    mesh_vox_opts o = {.channel = VOXEL_CH_DISTANCE, .band = band};
    engine_pipeline_job job = {.kind = &engine_kind_mesh, .mesh = {.mesh = &m, .opts = o},
                               .res = res, .lo = {-2, -2, -0.5}, .hi = {2, 2, 0.5}};
    vod_params_default(&job.vod);
    job.vod.channel = VOXEL_CH_DISTANCE;
    size_t empties = same_job(&job, (mpi_subtree_job){.kind = MPI_KIND_MESH, .mesh_opts = o},
                              target, workers);
    cr_assert(empties > 0, "the box has columns without a triangle");
    torus_free(&m);
}

Test(mpi_scheme, distance_columns_give_the_whole_grid_file)
{
    same_distance(160, 0, 8, 0);
    same_distance(130, 5, 8, 2);
}

/* The torus as an OBJ file's bytes. */
static char *torus_obj(size_t *len)
{
    mesh m = torus(16, 8, 0);
    size_t cap = 64 * ((size_t)m.n_vertices + m.n_triangles), n = 0;
    char *b = malloc(cap);
    for (uint32_t i = 0; i < m.n_vertices; i++)
        n += (size_t)snprintf(b + n, cap - n, "v %.6f %.6f %.6f\n", m.vertices[i][0],
                              m.vertices[i][1], m.vertices[i][2]);
    for (uint32_t t = 0; t < m.n_triangles; t++)
        n += (size_t)snprintf(b + n, cap - n, "f %u %u %u\n", m.triangles[t][0] + 1,
                              m.triangles[t][1] + 1, m.triangles[t][2] + 1);
    torus_free(&m);
    *len = n;
    return b;
}

#define TREE "ring = mesh \"ring.obj\" fit 0,0,0.1 scale 1.5\n"                   \
             "ball = implicit \"x^2 + y^2 + z^2 - 0.3\"\n"                         \
             "box = cuboid center 0.3,0,0 size 0.5,0.9,0.4\n"                      \
             "all = difference(union(erode(ring, 1), dilate(ball, 2)), box)\n"     \
             "result all\n"

/* TREE parsed, its mesh leaf's bytes given, then packed and unpacked as
 * a rank receives it (the caller frees both). */
static void tree_pair(csg_tree **parsed, csg_tree **got)
{
    csg_error ce;
    cr_assert_eq(csg_parse(TREE, strlen(TREE), parsed, &ce), 0, "%s", ce.msg);
    (*parsed)->data[0] = torus_obj(&(*parsed)->data_len[0]);
    uint8_t *buf;
    size_t n;
    cr_assert_eq(csg_tree_pack(*parsed, &buf, &n), 0);
    cr_assert_eq(csg_tree_unpack(buf, n, got), 0);
    free(buf);
}

static void same_csg(uint32_t res, int channel, size_t target, int workers)
{
    csg_tree *t, *u;
    tree_pair(&t, &u);
    engine_pipeline_job job = {.kind = &engine_kind_csg, .csg = {.tree = t}, .res = res,
                        .lo = {-1, -1, -1}, .hi = {1, 1, 1}};
    vod_params_default(&job.vod);
    job.vod.channel = channel;
    same_job(&job, (mpi_subtree_job){.kind = MPI_KIND_CSG, .tree = u}, target, workers);
    csg_tree_free(t);
    csg_tree_free(u);
}

/* A tree's distance: its band in the leaves (as vox_mpi sets it before
 * the broadcast), the mesh leaf f32, the levels above the float mean. */
static void same_csg_distance(uint32_t res, uint32_t band, size_t target, int workers)
{
    static const char text[] = "ring = mesh \"ring.obj\" fit 0,0,0.1 scale 1.5\n"
                               "ball = implicit \"x^2 + y^2 + z^2 - 0.3\"\n"
                               "all = difference(ring, ball)\nresult all\n";
    csg_tree *t;
    csg_error ce;
    cr_assert_eq(csg_parse(text, strlen(text), &t, &ce), 0, "%s", ce.msg);
    t->data[0] = torus_obj(&t->data_len[0]);
    engine_pipeline_job job = {.kind = &engine_kind_csg, .csg = {.tree = t}, .res = res,
                               .lo = {-1, -1, -1}, .hi = {1, 1, 1}, .band = band};
    vod_params_default(&job.vod);
    job.vod.channel = VOXEL_CH_DISTANCE;
    uint8_t *buf;
    size_t n;
    csg_tree *u;
    cr_assert_eq(csg_tree_pack(t, &buf, &n), 0);
    cr_assert_eq(csg_tree_unpack(buf, n, &u), 0);
    free(buf);
    csg_tree_set_band(u, band ? band : VOXEL_BAND_DEFAULT);
    same_job(&job, (mpi_subtree_job){.kind = MPI_KIND_CSG, .tree = u}, target, workers);
    csg_tree_free(t);
    csg_tree_free(u);
}

Test(mpi_scheme, csg_distance_subtrees_give_the_whole_grid_file)
{
    same_csg_distance(72, 0, 16, 0);
    same_csg_distance(64, 4, 8, 2);
}

Test(mpi_scheme, csg_subtrees_give_the_whole_grid_file)
{
    same_csg(100, VOXEL_CH_DENSITY, 16, 0);
    same_csg(90, VOXEL_CH_SURFACE, 8, 2);
    same_csg(70, VOXEL_CH_OCCUPANCY, 64, 1);
    same_csg(12, VOXEL_CH_DENSITY, 8, 0); /* below a storage brick: the whole grid */
}

Test(mpi_wire, damaged_trees_and_meshes_are_refused)
{
    csg_tree *t, *u;
    tree_pair(&t, &u);
    cr_assert_eq(u->n, t->n);
    cr_assert(!memcmp(u->node, t->node, t->n * sizeof *t->node));
    cr_assert_eq(u->data_len[0], t->data_len[0]);
    cr_assert(!memcmp(u->data[0], t->data[0], t->data_len[0]));
    uint8_t *buf;
    size_t n;
    cr_assert_eq(csg_tree_pack(t, &buf, &n), 0);
    csg_tree *bad = NULL;
    cr_assert_eq(csg_tree_unpack(buf, n - 1, &bad), -EPROTO, "a short buffer");
    t->node[t->n - 1].a = (int32_t)t->n - 1; /* a child that is not below its parent */
    free(buf);
    cr_assert_eq(csg_tree_pack(t, &buf, &n), 0);
    cr_assert_eq(csg_tree_unpack(buf, n, &bad), -EPROTO, "a child above its parent");
    cr_assert_null(bad);
    free(buf);
    csg_tree_free(t);
    csg_tree_free(u);

    mesh m = torus(8, 4, 0), part;
    cr_assert_eq(mpi_mesh_part(&m, NULL, NULL, &buf, &n), 0);
    cr_assert_eq(mpi_mesh_view(buf, n, &part), 0);
    cr_assert_eq(part.n_triangles, m.n_triangles);
    cr_assert_eq(part.n_vertices, m.n_vertices);
    cr_assert(part.lo[0] == m.lo[0] && part.hi[2] == m.hi[2]);
    cr_assert_eq(mpi_mesh_view(buf, n - 4, &part), -EPROTO, "a short buffer");
    uint32_t far = m.n_vertices;
    memcpy(buf + n - 4, &far, 4); /* the last triangle's last index */
    cr_assert_eq(mpi_mesh_view(buf, n, &part), -EPROTO, "an index past the vertices");
    free(buf);
    torus_free(&m);
}

Test(mpi_cut, grid_cut_covers_the_grid_once)
{
    grid_spec g = grid(200);
    vod_params p = params(&g, VOXEL_CH_DENSITY, 16);
    vod_layout L;
    err_info err = {0};
    cr_assert_eq(vod_layout_make(&p, g.depth, &L, &err), 0);
    for (int columns = 0; columns < 2; columns++) {
        mpi_cut c;
        cr_assert_eq(mpi_cut_grid(&g, &L, 24, columns ? 6 : 4, columns, &c), 0);
        cr_assert(c.n >= 24 || c.level == (columns ? 6 : 5), "%zu tasks", c.n);
        uint64_t cover = 0;
        for (size_t i = 0; i < c.n; i++) {
            grid_octant o = c.oct[i];
            cr_assert(o.level == c.level && o.x < 200 && o.y < 200 && o.z < 200);
            uint64_t side = 1u << o.level, e[3] = {o.x, o.y, o.z};
            uint64_t v = 1;
            for (int a = 0; a < (columns ? 2 : 3); a++)
                v *= (e[a] + side < 200 ? side : 200 - e[a]);
            cover += columns ? v * 200 : v;
        }
        cr_assert_eq(cover, 200ull * 200 * 200, "the tasks cover every voxel once");
        mpi_cut_free(&c);
    }
}
