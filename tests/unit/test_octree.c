/* The octree against a dense array: random stores in random and in preorder,
 * lookups, Figure 6 iteration (every voxel once, in preorder), full arena. */
#include <criterion/criterion.h>
#include <errno.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "octree.h"
#include "voxel.h"

#define DEPTH 5
#define N (1u << DEPTH)

static uint32_t key(uint32_t x, uint32_t y, uint32_t z) { return (z * N + y) * N + x; }

/* Morton (preorder) key: interleave bits, highest level first. */
static uint64_t morton(uint32_t x, uint32_t y, uint32_t z)
{
    uint64_t m = 0;
    for (int b = DEPTH - 1; b >= 0; b--)
        m = m << 3 | ((z >> b) & 1) << 2 | ((y >> b) & 1) << 1 | ((x >> b) & 1);
    return m;
}

static void fill_random(octree *t, uint32_t *dense, unsigned seed, int count)
{
    srand(seed);
    for (int i = 0; i < count; i++) {
        uint32_t x = rand() % N, y = rand() % N, z = rand() % N;
        uint32_t v = 1 + (uint32_t)rand();
        cr_assert_eq(octree_store(t, x, y, z, v), 0);
        dense[key(x, y, z)] = v;
    }
}

Test(octree, random_stores_match_dense_array)
{
    static octree_cell arena[20000];
    static uint32_t dense[N * N * N];
    octree t;
    octree_init(&t, arena, 20000, DEPTH);
    fill_random(&t, dense, 7, 3000);
    uint64_t count = 0;
    for (uint32_t z = 0; z < N; z++)
        for (uint32_t y = 0; y < N; y++)
            for (uint32_t x = 0; x < N; x++) {
                cr_assert_eq(octree_get(&t, x, y, z), dense[key(x, y, z)],
                             "voxel %u %u %u", x, y, z);
                count += dense[key(x, y, z)] != 0;
            }
    cr_assert_eq(t.voxels, count);
}

Test(octree, iteration_visits_every_voxel_once_in_preorder)
{
    static octree_cell arena[20000];
    static uint32_t dense[N * N * N];
    octree t;
    octree_init(&t, arena, 20000, DEPTH);
    fill_random(&t, dense, 11, 2000);
    octree_iter it;
    octree_iter_init(&it, &t);
    uint32_t x, y, z, v;
    uint64_t seen = 0, prev = 0;
    while (octree_iter_next(&it, &x, &y, &z, &v)) {
        cr_assert_eq(v, dense[key(x, y, z)]);
        dense[key(x, y, z)] = 0; /* twice would now mismatch */
        uint64_t m = morton(x, y, z);
        cr_assert(seen == 0 || m > prev, "not in preorder");
        prev = m;
        seen++;
    }
    cr_assert_eq(seen, t.voxels);
    for (uint32_t i = 0; i < N * N * N; i++) cr_assert_eq(dense[i], 0);
}

Test(octree, preorder_insertion_builds_the_same_tree)
{
    static octree_cell a1[20000], a2[20000];
    static uint32_t dense[N * N * N];
    octree t1, t2;
    octree_init(&t1, a1, 20000, DEPTH);
    octree_init(&t2, a2, 20000, DEPTH);
    fill_random(&t1, dense, 3, 1500);
    octree_iter it;
    octree_iter_init(&it, &t1);
    uint32_t x, y, z, v;
    while (octree_iter_next(&it, &x, &y, &z, &v))
        cr_assert_eq(octree_store(&t2, x, y, z, v), 0);
    cr_assert_eq(t2.voxels, t1.voxels);
    cr_assert_eq(t2.used, t1.used, "same cells whatever the order");
    for (uint32_t i = 0; i < N * N * N; i++)
        if (dense[i])
            cr_assert_eq(octree_get(&t2, i % N, i / N % N, i / N / N), dense[i]);
}

Test(octree, full_arena_is_enomem_and_leaves_tree_intact)
{
    static octree_cell arena[8];
    octree t;
    octree_init(&t, arena, 8, DEPTH);
    cr_assert_eq(octree_store(&t, 0, 0, 0, 5), 0); /* root + 4 cells */
    cr_assert_eq(octree_store(&t, 31, 31, 31, 6), -ENOMEM);
    cr_assert_eq(octree_get(&t, 0, 0, 0), 5);
    cr_assert_eq(octree_get(&t, 31, 31, 31), 0);
    cr_assert_eq(t.voxels, 1);
    cr_assert_eq(octree_store(&t, 1, 1, 1, 7), 0, "same leaf cell needs no new cell");
}

Test(octree, depth_one_tree)
{
    static octree_cell arena[4];
    octree t;
    octree_init(&t, arena, 4, 1);
    cr_assert_eq(octree_store(&t, 1, 0, 1, 9), 0);
    cr_assert_eq(octree_get(&t, 1, 0, 1), 9);
    cr_assert_eq(t.used, 2);
}

/* ---- subtrees built by several writers in one arena, then linked ---- */

#define SHARED_CELLS (3 * OCTREE_BLOCK_CELLS + 1)

/* A shared counter of blocks, block b being cells [1 + b*B, 1 + (b+1)*B);
 * block 0 is the linking tree's own (octree_init's first block). */
typedef struct {
    uint32_t next;
    uint32_t grabs;
} blocks;

static int grab_block(void *ud, uint32_t *first, uint32_t *end)
{
    blocks *b = ud;
    uint32_t f = 1 + b->next * OCTREE_BLOCK_CELLS;
    if (f >= SHARED_CELLS) return -ENOMEM;
    b->next++;
    b->grabs++;
    *first = f;
    *end = f + OCTREE_BLOCK_CELLS < SHARED_CELLS ? f + OCTREE_BLOCK_CELLS : SHARED_CELLS;
    return 0;
}

/* The voxels of one octant of the dense array, into subtree t (its own
 * coordinates), in preorder. */
static void build_octant(octree *t, const octree *whole, uint32_t ox, uint32_t oy,
                         uint32_t oz, int level)
{
    octree_subtree(t, level);
    octree_iter it;
    octree_iter_init(&it, whole);
    uint32_t x, y, z, v, n = 1u << level;
    while (octree_iter_next(&it, &x, &y, &z, &v))
        if (x - ox < n && y - oy < n && z - oz < n)
            cr_assert_eq(octree_store(t, x - ox, y - oy, z - oz, v), 0);
}

static void assert_same_voxels(const octree *a, const octree *b)
{
    octree_iter ia, ib;
    octree_iter_init(&ia, a);
    octree_iter_init(&ib, b);
    uint32_t p[4], q[4];
    uint64_t n = 0;
    while (octree_iter_next(&ia, &p[0], &p[1], &p[2], &p[3])) {
        cr_assert(octree_iter_next(&ib, &q[0], &q[1], &q[2], &q[3]), "b ends at %llu",
                  (unsigned long long)n);
        cr_assert_arr_eq(p, q, sizeof p, "voxel %llu", (unsigned long long)n);
        n++;
    }
    cr_assert_not(octree_iter_next(&ib, &q[0], &q[1], &q[2], &q[3]), "b has more");
    cr_assert_eq(a->voxels, n);
    cr_assert_eq(b->voxels, n);
}

/* Two writers build the level-3 octants alternately, their blocks
 * interleaved in the arena; the linking tree gets the same voxels and the
 * same number of cells as the tree built by stores. */
Test(octree, subtrees_from_two_writers_linked_make_the_stored_tree)
{
    static octree_cell ref_arena[20000], arena[SHARED_CELLS];
    static uint32_t dense[N * N * N];
    octree ref, t, w[2];
    octree_init(&ref, ref_arena, 20000, DEPTH);
    fill_random(&ref, dense, 5, 2500);
    memset(arena, 0xa5, sizeof arena); /* blocks are cleared as handed out */
    blocks b = {.next = 1};
    octree_init(&t, arena, SHARED_CELLS, DEPTH);
    octree_share(&t, grab_block, &b);
    for (int k = 0; k < 2; k++) octree_writer(&w[k], arena, SHARED_CELLS, grab_block, &b);
    uint32_t cells = t.taken, n = 0;
    for (uint32_t i = 0; i < 64; i++) {
        uint32_t ox = (i & 3) << 3, oy = (i >> 2 & 3) << 3, oz = (i >> 4) << 3;
        octree *s = &w[i & 1];
        build_octant(s, &ref, ox, oy, oz, 3);
        if (!s->root) {
            cr_assert_eq(s->taken, 0, "an empty subtree takes no cell");
            continue;
        }
        cr_assert_eq(octree_get(s, 0, 0, 0), dense[key(ox, oy, oz)]);
        uint32_t at[3] = {ox + 1, oy + 2, oz + 3}, again[3] = {ox, oy, oz};
        cr_assert_eq(octree_link(&t, at, 2, s->root, s->voxels), 0);
        cr_assert_eq(octree_link(&t, again, 2, s->root, s->voxels), -EEXIST);
        cells += s->taken;
        n++;
    }
    cr_assert_gt(n, 32);
    cr_assert_eq(b.grabs, 2, "each writer took one block of its own");
    cells += t.taken - 1; /* the linking tree's cells above the subtrees */
    t.used = SHARED_CELLS; /* the owner's view: every writer's blocks */
    assert_same_voxels(&ref, &t);
    cr_assert_eq(cells + 1, ref.used, "as many cells as stores make");
    for (uint32_t i = 0; i < N * N * N; i += 7)
        cr_assert_eq(octree_get(&t, i % N, i / N % N, i / N / N), dense[i]);
}

/* A subtree of the whole tree's size: its root's entries become the
 * root's. */
Test(octree, a_whole_tree_subtree_is_copied_into_the_root)
{
    static octree_cell ref_arena[20000], arena[SHARED_CELLS];
    static uint32_t dense[N * N * N];
    octree ref, t, w;
    octree_init(&ref, ref_arena, 20000, DEPTH);
    fill_random(&ref, dense, 9, 500);
    blocks b = {.next = 1};
    octree_init(&t, arena, SHARED_CELLS, DEPTH);
    octree_share(&t, grab_block, &b);
    octree_writer(&w, arena, SHARED_CELLS, grab_block, &b);
    build_octant(&w, &ref, 0, 0, 0, DEPTH);
    cr_assert_eq(w.voxels, ref.voxels);
    const uint32_t origin[3] = {0, 0, 0};
    cr_assert_eq(octree_link(&t, origin, DEPTH - 1, w.root, w.voxels), 0);
    cr_assert_eq(octree_link(&t, origin, DEPTH - 1, w.root, w.voxels), -EEXIST);
    t.used = SHARED_CELLS;
    assert_same_voxels(&ref, &t);
}

/* The shared arena runs out: the store that needs a cell fails with
 * -ENOMEM and leaves the subtree as it was. */
Test(octree, a_writer_without_blocks_gets_enomem)
{
    static octree_cell arena[SHARED_CELLS];
    blocks b = {.next = 3}; /* the last block, which is 1 cell */
    octree w;
    octree_writer(&w, arena, SHARED_CELLS, grab_block, &b);
    octree_subtree(&w, 4);
    cr_assert_eq(octree_store(&w, 1, 2, 3, 7), -ENOMEM);
    cr_assert_eq(w.root, 0);
    b.next = 2; /* a whole block: */
    cr_assert_eq(octree_store(&w, 1, 2, 3, 7), 0);
    cr_assert_eq(octree_get(&w, 1, 2, 3), 7);
    cr_assert_eq(w.taken, 4);
    cr_assert_eq(w.used, 1 + 3 * OCTREE_BLOCK_CELLS);
}

/* A garbage cell index (a broken writer's) reads as empty: iteration,
 * lookups and links stay inside the arena. */
Test(octree, an_index_past_used_reads_as_empty)
{
    static octree_cell arena[64];
    octree t;
    octree_init(&t, arena, 64, 3);
    cr_assert_eq(octree_store(&t, 0, 0, 0, 5), 0);
    cr_assert_eq(octree_store(&t, 7, 7, 7, 6), 0);
    arena[1].child[7] = 1u << 30; /* the (7,7,7) octant now points outside */
    cr_assert_eq(octree_get(&t, 7, 7, 7), 0);
    cr_assert_eq(octree_find(&t, 1, 7, 7, 7), 0);
    octree_iter it;
    octree_iter_init(&it, &t);
    uint32_t x, y, z, v, n = 0;
    while (octree_iter_next(&it, &x, &y, &z, &v)) n++;
    cr_assert_eq(n, 1);
    const uint32_t corner[3] = {7, 7, 7};
    cr_assert_eq(octree_link(&t, corner, 0, 2, 1), -EEXIST);
}

Test(voxel, octahedral_normals_round_trip_within_a_milliradian)
{
    srand(5);
    for (int i = 0; i < 100000; i++) {
        double n[3], m[3];
        for (int k = 0; k < 3; k++) n[k] = rand() / (double)RAND_MAX * 2 - 1;
        double l = sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
        if (l < 1e-6) continue;
        for (int k = 0; k < 3; k++) n[k] /= l;
        uint32_t v = voxel_surface(n);
        cr_assert_eq(voxel_occupancy(v), 255);
        voxel_unpack_normal(v, m);
        double dot = n[0] * m[0] + n[1] * m[1] + n[2] * m[2];
        cr_assert(dot > cos(1.5e-3), "normal %g %g %g: error %g rad", n[0], n[1], n[2], acos(dot));
    }
}

/* The packing as first written (quantize with floor()), which the VOD files
 * already written encode: the faster packing must give the same bits. */
static uint32_t ref_quantize(double u)
{
    double q = floor((u * 0.5 + 0.5) * 4095.0 + 0.5);
    if (!(q >= 0.0)) q = 0.0;
    if (q > 4095.0) q = 4095.0;
    return (uint32_t)q;
}

static uint32_t ref_pack(const double n[3])
{
    double l1 = fabs(n[0]) + fabs(n[1]) + fabs(n[2]);
    if (!(l1 > 0.0) || !isfinite(l1)) return ref_quantize(0.0) << 8 | ref_quantize(0.0) << 20;
    double u = n[0] / l1, v = n[1] / l1;
    if (n[2] < 0.0) {
        double fu = (1.0 - fabs(v)) * (u < 0.0 ? -1.0 : 1.0);
        double fv = (1.0 - fabs(u)) * (v < 0.0 ? -1.0 : 1.0);
        u = fu;
        v = fv;
    }
    return ref_quantize(u) << 8 | ref_quantize(v) << 20;
}

Test(voxel, packing_matches_the_floor_reference)
{
    srand(6);
    for (int i = 0; i < 1000000; i++) {
        double n[3];
        for (int k = 0; k < 3; k++) {
            int c = rand() % 12;
            n[k] = c == 0 ? 0.0 : c == 1 ? -0.0 : c == 2 ? (double)(rand() % 3 - 1)
                 : c == 3 ? ldexp(rand() % 2 ? 1 : -1, rand() % 2100 - 1070)
                 : c == 4 ? (rand() % 2 ? INFINITY : NAN)
                 : rand() / (double)RAND_MAX * 2 - 1;
        }
        cr_assert_eq(voxel_pack_normal(n), ref_pack(n), "%a %a %a", n[0], n[1], n[2]);
    }
    /* u on both sides of every rounding boundary (k - 1/2 after scaling) */
    for (int k = 0; k <= 4096; k++)
        for (int d = -2; d <= 2; d++) {
            double u = ((k - 1.0) / 4095.0 - 0.5) * 2 + d * 0x1p-52;
            double n[3] = {u, 0, 1 - fabs(u)};
            cr_assert_eq(voxel_pack_normal(n), ref_pack(n), "u = %a", u);
        }
}

Test(voxel, batched_packing_is_the_one_vector_packing)
{
    srand(7);
    for (int i = 0; i < 200000; i++) {
        double x[8], y[8], z[8];
        uint32_t out[8];
        for (int l = 0; l < 8; l++) {
            double *p[3] = {&x[l], &y[l], &z[l]};
            for (int k = 0; k < 3; k++) {
                int c = rand() % 12;
                *p[k] = c == 0 ? 0.0 : c == 1 ? -0.0 : c == 2 ? (double)(rand() % 3 - 1)
                      : c == 3 ? ldexp(rand() % 2 ? 1 : -1, rand() % 2100 - 1070)
                      : c == 4 ? (rand() % 2 ? INFINITY : NAN)
                      : rand() / (double)RAND_MAX * 2 - 1;
            }
        }
        unsigned n = 1 + (unsigned)rand() % 8;
        voxel_surfaces(x, y, z, n, out);
        for (unsigned l = 0; l < n; l++) {
            double v[3] = {x[l], y[l], z[l]};
            cr_assert_eq(out[l], voxel_surface(v), "%a %a %a", x[l], y[l], z[l]);
        }
    }
}
